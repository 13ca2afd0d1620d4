"""HMI: pops up an alert box for the driver when collision avoidance raises an alert.

Data flow:  Alerts::DriverAlerts on AlertTopic (transient local: a late HMI shows the last state)  -->  alert box

A WaitSet, not a listener, delivers the alerts: acknowledging an alert may take the driver a while, and that must not
block DDS's receive thread. The alert box is a window (SDL2 through pygame) when a display is available, or a clearly
marked box on the console (--ui console|window|auto). Losing and regaining the alert writer's liveliness is reported.

Redundant mode (config.redundant=true): the alerts come from the stronger live of two collision_avoidance instances;
each change of owner is reported in one line, the source is lost only when no writer is alive, and an alert state is
shown once however many writers repeat it.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Any, Protocol

from automotive.bus.app import Application, run
from automotive.bus.errors import ConfigError
from automotive.bus.ownership import OwnerTracker
from automotive.types.Alerts import DriverAlerts

ALERT_TEXTS = {
    "blindSpotDriver": "Vehicle in the blind spot, driver side",
    "blindSpotPassenger": "Vehicle in the blind spot, passenger side",
    "frontCollision": "Front collision warning",
    "backCollision": "Rear collision warning",
    "parkingCollision": "Parking collision warning",
    "driverAttention": "Driver attention required",
}
WINDOW_TITLE_ALERT = "HMI - DRIVER ALERT"
WINDOW_TITLE_CLEAR = "HMI - all clear"


def alert_texts(alert: DriverAlerts) -> list[str]:
    return [text for flag, text in ALERT_TEXTS.items() if getattr(alert, flag)]


class AlertUI(Protocol):
    def show(self, texts: list[str]) -> None: ...
    def clear(self) -> None: ...
    def source_alive(self, alive: bool) -> None: ...
    def pump(self) -> None: ...
    def close(self) -> None: ...


class ConsoleUI:
    """A boxed, unmistakable alert on standard output."""

    WIDTH = 56

    def _box(self, title: str, lines: list[str]) -> None:
        inner = self.WIDTH - 2
        print("+" + f" {title} ".center(inner, "=") + "+")
        for line in lines:
            print("| " + line.ljust(inner - 2) + " |")
        print("+" + "=" * inner + "+", flush=True)

    def show(self, texts: list[str]) -> None:
        self._box("!!! DRIVER ALERT !!!", texts)

    def clear(self) -> None:
        self._box("all clear", ["No alert"])

    def source_alive(self, alive: bool) -> None:
        if not alive:
            self._box("ALERT SOURCE LOST", ["Collision avoidance is not alive: alerts may be missing"])

    def pump(self) -> None:
        pass

    def close(self) -> None:
        pass


class WindowUI:
    """An SDL2 window (pygame): a red box with one line per alert, green when clear."""

    SIZE = (640, 260)

    def __init__(self) -> None:
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        import pygame

        self.pygame = pygame
        pygame.display.init()
        pygame.font.init()
        self.screen = pygame.display.set_mode(self.SIZE)
        self.title_font = pygame.font.Font(None, 48)
        self.text_font = pygame.font.Font(None, 32)
        self.texts: list[str] = []
        self.alive = True
        self._draw()

    def _draw(self) -> None:
        pygame = self.pygame
        alert = bool(self.texts)
        pygame.display.set_caption(WINDOW_TITLE_ALERT if alert else WINDOW_TITLE_CLEAR)
        self.screen.fill((30, 30, 30))
        box = pygame.Rect(20, 20, self.SIZE[0] - 40, self.SIZE[1] - 40)
        pygame.draw.rect(self.screen, (200, 0, 0) if alert else (0, 140, 0), box, border_radius=12)
        title = "DRIVER ALERT" if alert else "All clear"
        self.screen.blit(self.title_font.render(title, True, (255, 255, 255)), (box.x + 20, box.y + 16))
        lines = self.texts + ([] if self.alive else ["Alert source lost"])
        for index, line in enumerate(lines):
            self.screen.blit(self.text_font.render(line, True, (255, 255, 0)), (box.x + 20, box.y + 70 + index * 30))
        pygame.display.flip()

    def show(self, texts: list[str]) -> None:
        self.texts = texts
        self._draw()

    def clear(self) -> None:
        self.texts = []
        self._draw()

    def source_alive(self, alive: bool) -> None:
        self.alive = alive
        self._draw()

    def pump(self) -> None:
        for event in self.pygame.event.get():
            if event.type == self.pygame.QUIT:
                raise KeyboardInterrupt
        self.pygame.display.flip()

    def close(self) -> None:
        self.pygame.display.quit()


def make_ui(choice: str) -> AlertUI:
    if choice == "console":
        return ConsoleUI()
    if choice == "auto" and not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        return ConsoleUI()
    try:
        return WindowUI()
    except Exception as error:  # no pygame, or SDL cannot open the display
        if choice == "window":
            raise ConfigError(f"--ui window: cannot open a window ({error})") from None
        return ConsoleUI()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--ui", choices=["auto", "console", "window"], default="auto",
                        help="alert box in a window (SDL2), on the console, or a window when a display exists")


def body(app: Application) -> None:
    source_alive: list[bool] = []  # liveliness changes, appended by the listener thread, shown by the main loop

    def on_status(event: str, topic: str, status: Any) -> None:
        # The source is lost when no alert writer is alive (a hot standby may still be), back when one is again.
        if event == "liveliness_changed" and (status.not_alive_count_change > 0 or status.alive_count_change > 0):
            source_alive.append(status.alive_count > 0)

    alerts = app.reader("Alerts", DriverAlerts, "AlertTopic", hook=on_status)
    topic = alerts.topic.get_name()
    owner = OwnerTracker(alerts, app.log, app.stats)
    ui = make_ui(app.args.ui)
    app.log.info("HMI: %s alert box, waiting for alerts", "window" if isinstance(ui, WindowUI) else "console")

    shown: list[str] | None = None
    source_lost = False
    try:
        for _ in app.wake_ups(app.waitset(alerts), timeout_s=0.05 if isinstance(ui, WindowUI) else 1.0):
            ui.pump()
            while source_alive:
                alive = source_alive.pop(0)
                if alive != source_lost:  # no change: a writer came or went while another stayed alive
                    continue
                if not alive:
                    app.log.warning("alert source LOST: the alert writer's liveliness was lost")
                else:
                    app.log.info("alert source back: the alert writer's liveliness was regained")
                source_lost = not alive
                app.stats.record("source", alive=alive)  # what the driver is told: lost, or back
                ui.source_alive(alive)
            taken = alerts.take(N=100)
            taken_ns = time.time_ns()
            for alert in taken:
                if not isinstance(alert, DriverAlerts):
                    continue
                app.stats.record("take", topic=topic, src=alert.sample_info.source_timestamp,  # type: ignore[attr-defined]
                                 at=taken_ns, attention=alert.driverAttention)
                owner.follow(alert)
                texts = alert_texts(alert)
                if texts != shown:  # the writer repeats an active alert; the driver sees each change once
                    if texts:
                        app.log.info("DRIVER ALERT: %s", "; ".join(texts))
                        app.stats.record("shown", state="alert", texts=texts)
                        ui.show(texts)
                    else:
                        app.log.info("all clear")
                        app.stats.record("shown", state="clear", texts=[])
                        ui.clear()
                    shown = texts
                app.tick()
    finally:
        ui.close()


def main(argv: list[str] | None = None) -> int:
    return run("hmi", __doc__ or "", body, argv, add_arguments)


if __name__ == "__main__":
    sys.exit(main())
