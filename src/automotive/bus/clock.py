"""Timestamps of this host's clock in the types' formats."""

from __future__ import annotations

import time

from automotive.types.Common import POSIXTimestamp


def now_seconds_nanoseconds() -> tuple[int, int]:
    """This host's wall clock as (seconds, nanoseconds) since the epoch, as DDS and ROS 2 stamps hold it."""
    seconds, nanoseconds = divmod(time.time_ns(), 1_000_000_000)
    return seconds, nanoseconds


def now_timestamp() -> POSIXTimestamp:
    seconds, nanoseconds = now_seconds_nanoseconds()
    return POSIXTimestamp(s=seconds, ns=nanoseconds)


def timestamp_of(epoch_ns: int) -> POSIXTimestamp:
    """A time in ns since the epoch (a DDS source timestamp) as a POSIXTimestamp."""
    seconds, nanoseconds = divmod(epoch_ns, 1_000_000_000)
    return POSIXTimestamp(s=seconds, ns=nanoseconds)


def format_timestamp(stamp: POSIXTimestamp) -> str:
    return f"{stamp.s}.{stamp.ns:09d}"
