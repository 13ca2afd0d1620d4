"""Timestamps of this host's clock in the types' formats."""

from __future__ import annotations

import time

from automotive.types.Common import POSIXTimestamp


def now_timestamp() -> POSIXTimestamp:
    seconds, nanoseconds = divmod(time.time_ns(), 1_000_000_000)
    return POSIXTimestamp(s=seconds, ns=nanoseconds)


def format_timestamp(stamp: POSIXTimestamp) -> str:
    return f"{stamp.s}.{stamp.ns:09d}"
