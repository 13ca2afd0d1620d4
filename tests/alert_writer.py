"""A stand-in for collision_avoidance's alert writer, in a process of its own so that a test can kill it.

    python tests/alert_writer.py DOMAIN QOS_FILE

Writes Alerts::DriverAlerts on AlertTopic with the project's HMI QoS profile (from QOS_FILE). Each line on standard
input is one sample: the names of the flags to set (``frontCollision driverAttention``), or ``clear`` for none.
Prints ``ready`` once the writer exists and ``wrote ...`` after each sample.
"""

from __future__ import annotations

import sys
from pathlib import Path

from dds_helpers import make_bus

from automotive.bus.console import write_line
from automotive.types.Alerts import DriverAlerts

FLAGS = ("blindSpotDriver", "blindSpotPassenger", "frontCollision", "backCollision", "parkingCollision",
         "driverAttention")


def main() -> None:
    bus = make_bus(int(sys.argv[1]), Path(sys.argv[2]))
    writer = bus.writer("AlertTopic", DriverAlerts, "HMI")
    write_line("ready")
    for line in sys.stdin:
        flags = [word for word in line.split() if word != "clear"]
        unknown = set(flags) - set(FLAGS)
        if unknown:
            raise SystemExit(f"alert_writer: unknown flag(s) {sorted(unknown)}; expected {', '.join(FLAGS)}")
        writer.write(DriverAlerts(**{flag: flag in flags for flag in FLAGS}))
        write_line("wrote " + (" ".join(flags) or "clear"))
    bus.close()


if __name__ == "__main__":
    main()
