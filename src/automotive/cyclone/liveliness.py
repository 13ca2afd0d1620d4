"""A writer's liveliness asserted without writing: ``dds_assert_liveliness``, which Cyclone DDS Python does not bind.

A writer of MANUAL_BY_TOPIC liveliness stays alive only while someone asserts it: by writing, or by this call. The
site bridge (automotive.tools.zenoh.zenoh_bridge) asserts its writers of another site's topics while that site's writers
are alive, so that this site's readers see a writer lost when the other site's goes.

Reached through ``cyclonedds.internal.load_cyclonedds`` (libddsc) with a ctypes prototype written for libddsc 11:
only with the version gate open (:mod:`automotive.cyclone.gate`). With the gate closed, or a libddsc without the
symbol, :func:`asserter` is None and callers keep the profile's own liveliness (no liveliness carried).
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable
from typing import Any

from cyclonedds.core import DDSException
from cyclonedds.pub import DataWriter

from automotive.cyclone import gate

Asserter = Callable[[DataWriter[Any]], None]
_function: Any = None


def asserter() -> Asserter | None:
    """A function that asserts a writer's liveliness, or None (gate closed, or libddsc lacks the call)."""
    global _function
    if not gate.enabled():
        return None
    if _function is None:
        try:
            from cyclonedds.internal import load_cyclonedds

            function = load_cyclonedds().dds_assert_liveliness
        except (AttributeError, ImportError, OSError):
            return None
        function.argtypes = [ctypes.c_int32]
        function.restype = ctypes.c_int32
        _function = function
    call = _function

    def assert_liveliness(writer: DataWriter[Any]) -> None:
        result = int(call(writer._ref))
        if result < 0:
            raise DDSException(result, f"Occurred while asserting the liveliness of {writer!r}")

    return assert_liveliness
