"""The matched readers of a writer and writers of a reader, asked without Cyclone DDS Python's race.

Cyclone DDS Python 11.0.1's ``DataWriter.get_matched_subscriptions`` (and ``DataReader.get_matched_publications``)
asks libddsc for the number of matches, makes a buffer of that size and asks again to fill it; libddsc's second answer
is the number of matches *then*, and when an endpoint matched in between, Cyclone Python reads past its buffer and
raises ``IndexError: invalid index``. A peer that joins at that moment (a user's RTI tool, a monitor) would end the
application that asked: about 1 call in 100 raised it while readers came and went (tests/test_runtime.py). Asked again
here instead: the answer of a moment later is as true.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

ATTEMPTS = 100  # each one fails only if another endpoint matches within the few microseconds between two C calls


def matched_subscriptions(writer: Any) -> list[int]:
    """The instance handles of the readers matched with ``writer`` (``get_matched_subscriptions``)."""
    return _ask(writer.get_matched_subscriptions)


def matched_publications(reader: Any) -> list[int]:
    """The instance handles of the writers matched with ``reader`` (``get_matched_publications``)."""
    return _ask(reader.get_matched_publications)


def _ask(ask: Callable[[], list[int]]) -> list[int]:
    for _ in range(ATTEMPTS - 1):
        try:
            return ask()
        except IndexError:  # an endpoint matched between Cyclone Python's two calls: ask again
            continue
    return ask()
