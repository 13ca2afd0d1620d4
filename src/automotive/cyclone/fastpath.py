"""Octet sequences and octet arrays (de)serialized as one block instead of one element at a time.

Cyclone DDS Python 11.0.1 builds, for every member of an IDL type, a "machine" that writes and reads it. For a
``sequence<octet>`` (``types.sequence[types.uint8]``, bounded or not) it picks ``PlainCdrV2SequenceOfPrimitiveMachine``,
which packs the value with ``struct`` as one argument per byte and reads it back as a list of ints: 4 MiB take about
0.17 s to write. An ``octet[N]`` array already gets ``ByteArrayMachine`` (one block) but it copies the received
bytes twice. :func:`enable` replaces these machines, right after Cyclone's ``Builder.build_machines`` made them, with
subclasses that:

- write from ``bytes``, ``bytearray``, ``memoryview``, ``array.array('B')`` or a numpy ``uint8`` array (any shape,
  C order) in one block, and still from a list (or any iterable) of ints 0..255, as before;
- deliver the member as ``bytes``, one copy out of the received sample, which ``np.frombuffer(value, np.uint8)``
  views without a further copy;
- produce the same bytes on the wire as the machines they replace (XCDR1 and XCDR2, both byte orders: the CDR of an
  octet sequence is a 4-byte length then the bytes; an octet array is just the bytes);
- refuse a value over the member's bound (the IDL bound, or one registered with :func:`enforce_bound` for members
  the generated types must leave unbounded) with a :class:`OctetBoundError` naming the member and the bound.

Being subclasses, the new machines keep what Cyclone asks of the old ones elsewhere (XCDR2 member-length codes of
mutable types, key scanning, key machine ops). Cyclone wraps errors raised inside a struct in a bare ``Exception``
whose message prints the whole value; while enabled, ``IDL.serialize`` re-raises our own error instead.

Call :func:`enable` before the first sample is written or read (``automotive.cyclone.start`` does it once, when a
program starts). It also converts types whose machines were already built, so the order is not critical, but a type
whose machines are being built by another thread at that very moment may stay on the slow path: enable early, before
any DDS entity.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from cyclonedds.idl import IdlStruct, IdlUnion
from cyclonedds.idl._builder import Builder
from cyclonedds.idl._machinery import (
    ArrayMachine,
    ByteArrayMachine,
    DelimitedCdrAppendableStructMachine,
    DelimitedCdrAppendableUnionMachine,
    KeyEnabled,
    Machine,
    OptionalMachine,
    PlainCdrV2SequenceOfPrimitiveMachine,
    PLCdrMutableStructMachine,
    SequenceMachine,
    StructMachine,
    UnionMachine,
)
from cyclonedds.idl._main import IDL
from cyclonedds.idl._support import Buffer, DeserializeKind, SerializeKind
from cyclonedds.idl._type_normalize import get_extended_type_hints
from cyclonedds.idl.types import uint8

from automotive.cyclone import bounds
from automotive.cyclone.bounds import BoundError

__all__ = [
    "FastPathCounts",
    "OctetBoundError",
    "OctetValueError",
    "counts",
    "disable",
    "enable",
    "enabled",
    "enforce_bound",
    "uses_fast_path",
]


class OctetBoundError(BoundError):
    """An octet sequence longer than its bound (the IDL's or one registered with :func:`enforce_bound`)."""


class OctetValueError(ValueError):
    """A value that is not bytes-like nor a sequence of ints 0..255, or an octet array of the wrong size."""


_BYTE_FORMATS = ("B", "c")


def _as_block(value: Any, label: str) -> bytes | bytearray | memoryview:
    """The bytes of ``value`` as one buffer, copied only when they are not contiguous or not unsigned bytes."""
    if isinstance(value, (bytes, bytearray)):
        return value
    if isinstance(value, (int, str)):  # bytes(5) would be five zeros and bytes("a") an error about encodings
        raise OctetValueError(f"{label}: expected bytes-like or a sequence of ints 0..255, got {type(value).__name__}")
    try:
        view = memoryview(value)
    except TypeError:
        view = None
    if view is not None and view.itemsize == 1 and view.format.lstrip("@=<>!") in _BYTE_FORMATS:
        if view.ndim == 1 and view.format == "B" and view.c_contiguous:
            return view
        if view.c_contiguous:
            return view.cast("B")  # a 2-D image, or the 'c' / '<B' formats: same bytes, flat
        return view.tobytes()  # a strided view: one copy, in C order
    # Anything else (a list of ints, a numpy array of a wider integer type) is converted element by element, with
    # the same rule as Cyclone's struct.pack("B"): every element an int in 0..255.
    try:
        return bytes(iter(value))
    except (TypeError, ValueError) as error:
        expected = "expected bytes-like or a sequence of ints 0..255"
        raise OctetValueError(f"{label}: {expected}, got {type(value).__name__} ({error})") from None


def _read_block(buffer: Buffer, length: int, label: str) -> bytes:
    """``length`` bytes at the buffer's position, copied once (Buffer.read_bytes copies twice)."""
    start = buffer.tell()
    end = start + length
    data = buffer._bytes  # Buffer has no public accessor for its storage
    if end > len(data):
        raise OctetValueError(f"{label}: {length} bytes announced but only {len(data) - start} left in the sample")
    with memoryview(data) as view:
        block = bytes(view[start:end])
    buffer.seek(end)
    return block


class OctetSequenceMachine(PlainCdrV2SequenceOfPrimitiveMachine):
    """``sequence<octet[, N]>`` as a 4-byte length and one block of bytes."""

    def __init__(self, replaced: PlainCdrV2SequenceOfPrimitiveMachine, label: str, extra_bound: int | None):
        super().__init__(uint8, max_length=replaced.max_length)
        self.replaced = replaced
        self.label = label
        self.limit: int | None = None
        self.set_extra_bound(extra_bound)
        self.writes = 0
        self.reads = 0

    def set_extra_bound(self, extra_bound: int | None) -> None:
        limits = [b for b in (self.max_length, extra_bound) if b]
        self.limit = min(limits) if limits else None

    def serialize(self, buffer: Buffer, value: Any, serialize_kind: SerializeKind = SerializeKind.DataSample,
                  key_enabled: KeyEnabled = KeyEnabled.InKeylist) -> None:
        block = _as_block(value, self.label)
        length = len(block)
        if self.limit is not None and length > self.limit:
            raise OctetBoundError(f"{self.label} holds {length} bytes, over its bound of {self.limit} bytes")
        buffer.align(4)
        buffer.write("I", 4, length)
        if length:
            buffer.write_bytes(block)  # type: ignore[arg-type]  # any bytes-like object: it is sliced in
        self.writes += 1

    def deserialize(self, buffer: Buffer, deserialize_kind: DeserializeKind = DeserializeKind.DataSample,
                    key_enabled: KeyEnabled = KeyEnabled.InKeylist) -> bytes:
        buffer.align(4)
        length = buffer.read("I", 4)
        self.reads += 1
        return _read_block(buffer, length, self.label) if length else b""

    def default_initialize(self) -> bytes:
        return b""


class OctetArrayMachine(ByteArrayMachine):
    """``octet[N]``: exactly N bytes, one block; reads copy once instead of twice."""

    def __init__(self, replaced: ByteArrayMachine, label: str):
        super().__init__(replaced.size)
        self.replaced = replaced
        self.label = label
        self.writes = 0
        self.reads = 0

    def serialize(self, buffer: Buffer, value: Any, serialize_kind: SerializeKind = SerializeKind.DataSample,
                  key_enabled: KeyEnabled = KeyEnabled.InKeylist) -> None:
        block = _as_block(value, self.label)
        if len(block) != self.size:
            raise OctetValueError(f"{self.label} holds {len(block)} bytes; the array has exactly {self.size}")
        buffer.write_bytes(block)  # type: ignore[arg-type]  # any bytes-like object: it is sliced in
        self.writes += 1

    def deserialize(self, buffer: Buffer, deserialize_kind: DeserializeKind = DeserializeKind.DataSample,
                    key_enabled: KeyEnabled = KeyEnabled.InKeylist) -> bytes:
        self.reads += 1
        return _read_block(buffer, self.size, self.label)


_FAST_MACHINES = (OctetSequenceMachine, OctetArrayMachine)


# --- walking the machines of a type -------------------------------------------------------------------------------

_lock = threading.RLock()
_enabled = False
_original_build_machines: Callable[..., Any] = Builder.build_machines.__func__  # type: ignore[attr-defined]
_original_serialize: Callable[..., bytes] = IDL.serialize


def _is_octet_sequence(machine: Machine) -> bool:
    # exact class: an OctetSequenceMachine is handled separately, other subclasses are someone else's business
    return (type(machine) is PlainCdrV2SequenceOfPrimitiveMachine and machine.code == "B"  # type: ignore[attr-defined]
            and machine.size == 1)  # type: ignore[attr-defined]


Convert = Callable[[Machine, str, "int | None"], Machine]


def _to_fast(machine: Machine, label: str, extra_bound: int | None) -> Machine:
    if isinstance(machine, OctetSequenceMachine):
        machine.label = label
        machine.set_extra_bound(extra_bound)
        return machine
    if isinstance(machine, OctetArrayMachine):
        machine.label = label
        return machine
    if _is_octet_sequence(machine):
        return OctetSequenceMachine(machine, label, extra_bound)  # type: ignore[arg-type]
    if type(machine) is ByteArrayMachine:
        return OctetArrayMachine(machine, label)
    return machine


def _to_original(machine: Machine, label: str, extra_bound: int | None) -> Machine:
    return machine.replaced if isinstance(machine, _FAST_MACHINES) else machine  # type: ignore[attr-defined]


def _convert(machine: Machine, convert: Convert, label: str, extra_bound: int | None) -> Machine:
    """``machine`` converted, or with its sub-machines converted (optional, array and sequence members)."""
    new = convert(machine, label, extra_bound)
    if new is not machine:
        return new
    if isinstance(machine, (OptionalMachine, ArrayMachine, SequenceMachine)):
        element_label = label if isinstance(machine, OptionalMachine) else f"{label}[]"
        machine.submachine = _convert(machine.submachine, convert, element_label, extra_bound)
    return machine


def _member_slots(machine: Machine) -> Iterator[tuple[str, Callable[[], Machine], Callable[[Machine], None]]]:
    """(member or case name, getter, setter) of every member machine of a struct or union machine."""
    if isinstance(machine, StructMachine):
        table = machine.members_machines
    elif isinstance(machine, DelimitedCdrAppendableStructMachine):
        table = machine.member_machines
    elif isinstance(machine, PLCdrMutableStructMachine):
        for member in machine.mutablemembers:
            yield (member.name, (lambda m=member: m.machine),  # type: ignore[misc]
                   (lambda new, m=member: setattr(m, "machine", new)))  # type: ignore[misc]
        return
    elif isinstance(machine, (UnionMachine, DelimitedCdrAppendableUnionMachine)):
        table = machine.labels_submachines
        if machine.default is not None:
            yield "default", (lambda: machine.default), (lambda new: setattr(machine, "default", new))
    else:
        return
    for name in list(table):
        yield str(name), (lambda n=name: table[n]), (lambda new, n=name: table.__setitem__(n, new))  # type: ignore[misc]


def _rewrite_machine(cls: type, machine: Machine, convert: Convert) -> None:
    for name, get, put in _member_slots(machine):
        label = f"{bounds.type_name(cls)}.{name}"
        put(_convert(get(), convert, label, bounds.EXTRA_BOUNDS.get((cls, name))))


def _rewrite_type(cls: type, convert: Convert) -> None:
    idl = cls.__idl__  # type: ignore[attr-defined]
    with idl._lock:  # waits for a build in progress in another thread
        for machine in (idl.v1_machine, idl.v2_machine):
            if machine is not None:
                _rewrite_machine(cls, machine, convert)


def _idl_types() -> Iterator[type]:
    pending: list[type] = [IdlStruct, IdlUnion]
    seen: set[type] = set()
    while pending:
        cls = pending.pop()
        sub: type
        for sub in cls.__subclasses__():
            if sub not in seen:
                seen.add(sub)
                pending.append(sub)
                if getattr(sub, "__idl__", None) is not None:
                    yield sub


def _build_machines(cls: type[Builder], data_type: type) -> Any:
    """Cyclone's Builder.build_machines, then its octet machines replaced (runs under the type's IDL lock)."""
    built = _original_build_machines(cls, data_type)
    for machine in built[:2]:
        _rewrite_machine(data_type, machine, _to_fast)
    return built


def _fast_path_cause(error: BaseException) -> BaseException | None:
    seen = 0
    cause: BaseException | None = error
    while cause is not None and seen < 64:
        if isinstance(cause, (OctetBoundError, OctetValueError)):
            return cause
        cause = cause.__cause__
        seen += 1
    return None


def _serialize(self: IDL, *args: Any, **kwargs: Any) -> bytes:
    """IDL.serialize; our own error instead of Cyclone's 'Failed to encode member ..., value is <whole value>'."""
    try:
        return _original_serialize(self, *args, **kwargs)
    except Exception as error:
        cause = _fast_path_cause(error)
        if cause is None or cause is error:
            raise
        raise cause from None


# --- public API -----------------------------------------------------------------------------------------------------

def enable() -> None:
    """Switch octet sequences and arrays of every IDL type, built or still to build, to the fast path. Idempotent.

    Also enforces every bound listed in ``automotive.cyclone.bounds.EXTRA_BOUNDS`` (PointCloud2_.data_).
    """
    global _enabled
    with _lock:
        if not _enabled:
            Builder.build_machines = classmethod(_build_machines)  # type: ignore[method-assign, assignment]
            IDL.serialize = _serialize  # type: ignore[method-assign]
            _enabled = True
        for cls in _idl_types():
            _rewrite_type(cls, _to_fast)


def disable() -> None:
    """Restore Cyclone's own machines everywhere (for comparisons and benchmarks). Idempotent."""
    global _enabled
    with _lock:
        if _enabled:
            Builder.build_machines = classmethod(_original_build_machines)  # type: ignore[method-assign, assignment]
            IDL.serialize = _original_serialize  # type: ignore[method-assign]
            _enabled = False
        for cls in _idl_types():
            _rewrite_type(cls, _to_original)


def enabled() -> bool:
    return _enabled


def _member_hint(cls: type, member: str) -> Any:
    hints = get_extended_type_hints(cls)
    if member not in hints:
        raise KeyError(f"{bounds.type_name(cls)} has no member '{member}' (members: {', '.join(hints)})")
    return hints[member]


def enforce_bound(cls: type, member: str, bound: int) -> None:
    """Refuse, on write, more than ``bound`` bytes in the octet sequence ``cls.member`` (with the fast path enabled).

    For bounds the generated type cannot carry (Cyclone Python rejects sequence bounds above 65,535). With an IDL
    bound as well, the smaller one applies. Takes effect at once, also for types already in use.
    """
    _member_hint(cls, member)
    if isinstance(bound, bool) or not isinstance(bound, int) or bound <= 0:
        raise ValueError(f"bound of {bounds.type_name(cls)}.{member}: expected a positive int, got {bound!r}")
    with _lock:
        bounds.set_extra_bound(cls, member, bound)
        if _enabled:
            _rewrite_type(cls, _to_fast)


def _member_machines(cls: type, member: str) -> list[Machine]:
    _member_hint(cls, member)
    idl = cls.__idl__  # type: ignore[attr-defined]
    if not idl._populated:
        idl.populate()
    found = []
    for machine in (idl.v1_machine, idl.v2_machine):
        for name, get, _ in _member_slots(machine):
            if name == member:
                sub = get()
                while isinstance(sub, OptionalMachine):
                    sub = sub.submachine
                found.append(sub)
    return found


def uses_fast_path(cls: type, member: str) -> bool:
    """True when both the XCDR1 and the XCDR2 machine of ``cls.member`` write and read it as one block.

    Builds the type's machines if needed. False for members that are not octet sequences or arrays.
    """
    machines = _member_machines(cls, member)
    return bool(machines) and all(isinstance(m, _FAST_MACHINES) for m in machines)


@dataclass(frozen=True)
class FastPathCounts:
    writes: int
    reads: int


def counts(cls: type, member: str) -> FastPathCounts:
    """How many times ``cls.member`` was written and read through the fast path (XCDR1 and XCDR2 together)."""
    machines = [m for m in _member_machines(cls, member) if isinstance(m, _FAST_MACHINES)]
    return FastPathCounts(sum(m.writes for m in machines), sum(m.reads for m in machines))  # type: ignore[attr-defined]
