"""The HMI: console alert box, late joiner, and the SDL2 window on a virtual display."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

from dds_helpers import make_bus, wait_until

from automotive.types.Alerts import DriverAlerts

CLEAR = dict(blindSpotDriver=False, blindSpotPassenger=False, frontCollision=False, backCollision=False,
             parkingCollision=False, driverAttention=False)


def alert(**flags: bool) -> DriverAlerts:
    return DriverAlerts(**{**CLEAR, **flags})


def test_console_alert_box_with_a_text_per_flag(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    bus = make_bus(domain_id)
    writer = bus.writer("AlertTopic", DriverAlerts, "HMI")
    hmi = apps.start("hmi", "--ui", "console", "--domain", str(domain_id))
    hmi.wait_for("waiting for alerts")
    wait_until(lambda: len(writer.get_matched_subscriptions()) == 1, what="the HMI's reader")
    writer.write(alert(frontCollision=True, blindSpotPassenger=True))
    hmi.wait_for(r"DRIVER ALERT: Vehicle in the blind spot, passenger side; Front collision warning")
    hmi.wait_for(r"^\| Front collision warning")
    writer.write(alert())
    hmi.wait_for(r"hmi: all clear")
    bus.close()


def test_late_joining_hmi_shows_the_last_alert(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    bus = make_bus(domain_id)
    writer = bus.writer("AlertTopic", DriverAlerts, "HMI")
    writer.write(alert(parkingCollision=True))
    writer.write(alert(driverAttention=True))  # history 1: only this one is kept for late joiners
    hmi = apps.start("hmi", "--ui", "console", "--domain", str(domain_id))
    hmi.wait_for("DRIVER ALERT: Driver attention required")
    assert hmi.count("Parking collision") == 0
    bus.close()


def window_names(display: str) -> str:
    return subprocess.run(["xwininfo", "-root", "-tree"], env={**os.environ, "DISPLAY": display},
                          capture_output=True, text=True, timeout=10).stdout


def test_window_shows_the_alert_box(apps, domain_id: int, virtual_display: str,  # type: ignore[no-untyped-def]
                                    tmp_path: Path) -> None:
    from PIL import ImageGrab

    bus = make_bus(domain_id)
    writer = bus.writer("AlertTopic", DriverAlerts, "HMI")
    hmi = apps.start("hmi", "--ui", "window", "--domain", str(domain_id), env={"DISPLAY": virtual_display})
    hmi.wait_for("HMI: window alert box")
    wait_until(lambda: "HMI - all clear" in window_names(virtual_display), what="the HMI window")
    wait_until(lambda: len(writer.get_matched_subscriptions()) == 1, what="the HMI's reader")
    writer.write(alert(driverAttention=True, backCollision=True))
    hmi.wait_for("DRIVER ALERT")
    wait_until(lambda: "HMI - DRIVER ALERT" in window_names(virtual_display), what="the alert window title")

    def red_box_shown() -> bool:
        shot = ImageGrab.grab(xdisplay=virtual_display)
        shot.save(tmp_path / "hmi.png")
        colours = shot.convert("RGB").getcolors(maxcolors=1 << 20) or []
        counts = {rgb: n for n, rgb in colours}
        # the red alert box covers most of the 640x260 window; the alert texts are drawn in yellow
        return counts.get((200, 0, 0), 0) > 50_000 and counts.get((255, 255, 0), 0) > 200

    wait_until(red_box_shown, what="a red alert box with yellow text in the screenshot")
    writer.write(alert())
    hmi.wait_for("hmi: all clear")
    wait_until(lambda: "HMI - all clear" in window_names(virtual_display), what="the all-clear window title")
    bus.close()
