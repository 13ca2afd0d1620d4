"""The driver alerts in words: each member of Alerts::DriverAlerts as the HMI shows it (the monitor shows the same)."""

from __future__ import annotations

from automotive.types.Alerts import DriverAlerts

ALERT_TEXTS = {
    "blindSpotDriver": "Vehicle in the blind spot, driver side",
    "blindSpotPassenger": "Vehicle in the blind spot, passenger side",
    "frontCollision": "Front collision warning",
    "backCollision": "Rear collision warning",
    "parkingCollision": "Parking collision warning",
    "driverAttention": "Driver attention required",
}


def raised(alert: DriverAlerts) -> list[str]:
    """The members of ``alert`` that are set, in ALERT_TEXTS' order."""
    return [name for name in ALERT_TEXTS if bool(getattr(alert, name, False))]


def alert_texts(alert: DriverAlerts) -> list[str]:
    """The words of each alert raised in ``alert``."""
    return [ALERT_TEXTS[name] for name in raised(alert)]
