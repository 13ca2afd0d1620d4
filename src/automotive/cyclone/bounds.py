"""IDL bounds of sequences and strings, checked before a sample is written, with a clear message.

Cyclone Python refuses an over-bound sequence deep in its serializer with a message that prints the whole value;
this check names the type, the member, the length and the bound instead. It also enforces bounds the generated
types cannot express (Cyclone Python rejects sequence bounds above 65,535): see EXTRA_BOUNDS.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from functools import cache
from typing import Any

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, bounded_str, sequence, typedef

from automotive.cyclone import gate
from automotive.types.sensor_msgs.msg.dds_ import POINT_CLOUD_MAX_DATA, PointCloud2_

# (type, member) -> bound, for bounds of the original IDL that the generated code leaves out. The one registry of
# them: bounds.check and the octet fast path both read it. Change it with set_extra_bound.
EXTRA_BOUNDS: dict[tuple[type, str], int] = {
    (PointCloud2_, "data_"): POINT_CLOUD_MAX_DATA,
}


class BoundError(ValueError):
    """A sequence or string longer than its IDL bound."""


@dataclass(frozen=True)
class _MemberCheck:
    name: str
    bound: int | None  # None: unbounded, only the elements are checked
    element_type: type | None  # a struct whose own members need checking, else None


def set_extra_bound(cls: type, member: str, bound: int) -> None:
    """Add or change a bound the generated type cannot carry; with an IDL bound as well, the smaller one applies."""
    EXTRA_BOUNDS[(cls, member)] = bound
    _plan.cache_clear()


def _smaller_bound(*candidates: int | None) -> int | None:
    given = [bound for bound in candidates if bound]
    return min(given) if given else None


def member_types(cls: type) -> dict[str, Any]:
    """Each member's IDL type as Cyclone resolves it (``sequence[uint8, 10]``, ``bounded_str[128]``, a struct...).

    Cyclone's own resolver (a private module) on the tested version; otherwise the same answer from the public
    annotations: the generated code writes ``types.sequence[...]`` as ``Annotated[..., sequence(...)]``.
    """
    if gate.enabled():
        from cyclonedds.idl._type_normalize import get_extended_type_hints

        return dict(get_extended_type_hints(cls))
    resolved = {}
    for name, hint in typing.get_type_hints(cls, include_extras=True).items():
        metadata = getattr(hint, "__metadata__", ())
        idl_type = next((item for item in metadata if isinstance(item, (sequence, bounded_str, array, typedef))), None)
        resolved[name] = idl_type if idl_type is not None else hint
    return resolved


def type_name(cls: type) -> str:
    """The IDL name of a generated type, as messages and other vendors' tools say it (``Sensor::SensorObjectList``)."""
    return str(getattr(cls, "__idl_typename__", cls.__name__)).replace(".", "::")


@cache
def _plan(cls: type) -> tuple[_MemberCheck, ...]:
    checks = []
    for name, hint in member_types(cls).items():
        bound = EXTRA_BOUNDS.get((cls, name))
        element: type | None = None
        if isinstance(hint, sequence):
            bound = _smaller_bound(bound, hint.max_length)
            subtype = hint.subtype
            if isinstance(subtype, type) and issubclass(subtype, IdlStruct) and _plan(subtype):
                element = subtype
        elif isinstance(hint, bounded_str):
            bound = hint.max_length
        elif isinstance(hint, type) and issubclass(hint, IdlStruct) and _plan(hint):
            checks.append(_MemberCheck(name, None, hint))
            continue
        if bound or element:
            checks.append(_MemberCheck(name, bound, element))
    return tuple(checks)


def check(sample: Any, path: str = "") -> None:
    """Raise BoundError if any bounded sequence or string of ``sample`` is over its IDL bound."""
    cls = type(sample)
    for member in _plan(cls):  # type: ignore[arg-type]  # a class is hashable
        value = getattr(sample, member.name)
        if member.bound is not None and len(value) > member.bound:
            unit = "characters" if isinstance(value, str) else "elements"
            raise BoundError(f"{path or type_name(cls)}.{member.name} holds {len(value)} {unit}, over its IDL bound "
                             f"of {member.bound}")
        if member.element_type is not None:
            prefix = path or type_name(cls)
            if isinstance(value, IdlStruct):
                check(value, f"{prefix}.{member.name}")
            else:
                for index, element in enumerate(value):
                    check(element, f"{prefix}.{member.name}[{index}]")
