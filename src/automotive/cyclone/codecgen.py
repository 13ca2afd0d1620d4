"""Generates ``automotive/types/codecs.py``: a fast CDR codec for every struct type of the package's IDL.

Build-time only: run by ``scripts/generate-types`` right after idlc, on the types it just generated (``--check``
compares the result with the committed file, like the types); nothing at run time imports this module. Usage::

    python -m automotive.cyclone.codecgen TYPES_DIR > TYPES_DIR/codecs.py

It lives in automotive.cyclone because it reads Cyclone's type hints the way Cyclone's builder does (a private
function of cyclonedds). The generated module imports nothing of the project but the generated types: its helpers are
written into it (:data:`PRELUDE`), and the registry (automotive.cyclone.codecs) binds ``EXTRA_BOUNDS`` to
automotive.cyclone.bounds' and makes ``Codec`` objects of its ``CODEC_PARTS``.

The input is what Cyclone DDS Python's own serializer works from: the annotations of the generated dataclasses, read
with the same function Cyclone's builder uses. The output mirrors Cyclone's serializer rule by rule (its
``_machinery.py`` and ``_builder.py`` in cyclonedds 11.0.1), so that it produces the same bytes:

- XCDR1 aligns a member to its size, at most 8; XCDR2 at most 4; offsets count from the end of the 4-byte
  encapsulation header.
- XCDR2 puts a 4-byte DHEADER (the byte length of what follows) before an appendable struct, before a sequence whose
  elements are not primitive and before an array of structs; XCDR1 has none of them.
- A sequence is a 4-byte length, then its elements; a string is its UTF-8 length + 1, the bytes, a NUL.
- Enums are 4-byte unsigned; an unknown value decodes to the int, as Cyclone does; booleans are ``struct``'s '?'.
- Reading an appendable struct in XCDR2, members past its DHEADER's length take their defaults and bytes beyond the
  last known member are skipped (type evolution), as Cyclone does.

Where the position modulo the alignment is known when generating, padding is a constant inside one precompiled
``struct`` format for a run of consecutive fixed-size members; after a string or a sequence it is computed at run
time. Sequences of fixed-size structs are read in bulk (``Struct.iter_unpack``) or viewed as numpy structured arrays.

Not supported (no codec is generated; Cyclone's serializer handles such types): unions, mutable structs, optional
members, maps, char/wchar, bit-bound enums, sequences or arrays of strings, enums, sequences or nested arrays.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import importlib
import inspect
import pkgutil
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any

import cyclonedds.idl.types as idl_types
from cyclonedds.idl import IdlStruct
from cyclonedds.idl._type_normalize import get_extended_type_hints  # what Cyclone's builder reads; generation only

# IDL primitive -> (struct code, size). The same table as Cyclone's (plain int and float are 64-bit there too).
PRIMITIVES: dict[Any, tuple[str, int]] = {
    idl_types.int8: ("b", 1), idl_types.int16: ("h", 2), idl_types.int32: ("i", 4), idl_types.int64: ("q", 8),
    idl_types.uint8: ("B", 1), idl_types.byte: ("B", 1), idl_types.uint16: ("H", 2), idl_types.uint32: ("I", 4),
    idl_types.uint64: ("Q", 8), idl_types.float32: ("f", 4), idl_types.float64: ("d", 8),
    int: ("q", 8), float: ("d", 8), bool: ("?", 1),
}
NUMPY_CODES = {"b": "i1", "h": "i2", "i": "i4", "q": "i8", "B": "u1", "H": "u2", "I": "u4", "Q": "u8", "f": "f4",
               "d": "f8", "?": "?"}
SMALL_ARRAY = 16  # primitive arrays up to this length are unpacked into names (one format with their neighbours)


class Unsupported(Exception):  # noqa: N818 - a reason, reported in the generated file
    pass


# --- the model: what each member is ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Prim:
    code: str
    size: int

    @property
    def default(self) -> str:
        return {"?": "False", "f": "0.0", "d": "0.0"}.get(self.code, "0")


@dataclass(frozen=True)
class EnumNode:
    cls: type
    default: str  # repr of Cyclone's default (its __idl_enum_default_value__)


@dataclass(frozen=True)
class Str:
    bound: int | None


@dataclass(frozen=True)
class OctetArray:
    length: int


@dataclass(frozen=True)
class OctetSeq:
    bound: int | None


@dataclass(frozen=True)
class PrimArray:
    prim: Prim
    length: int


@dataclass(frozen=True)
class PrimSeq:
    prim: Prim
    bound: int | None


@dataclass(eq=False)
class Model:
    cls: type
    label: str  # Sensor::SensorObjectList
    ident: str  # Sensor_SensorObjectList
    appendable: bool
    members: list[tuple[str, Any]] = field(default_factory=list)


@dataclass(frozen=True, eq=False)
class StructNode:
    model: Model


@dataclass(frozen=True, eq=False)
class StructArray:
    model: Model
    length: int


@dataclass(frozen=True, eq=False)
class StructSeq:
    model: Model
    bound: int | None


Node = Prim | EnumNode | Str | OctetArray | OctetSeq | PrimArray | PrimSeq | StructNode | StructArray | StructSeq


class Models:
    def __init__(self) -> None:
        self.models: dict[type, Model] = {}
        self.unsupported: dict[type, str] = {}

    def model(self, cls: type) -> Model:
        if cls in self.unsupported:
            raise Unsupported(self.unsupported[cls])
        if cls in self.models:
            return self.models[cls]
        annotations = getattr(cls, "__idl_annotations__", {})
        extensibility = annotations.get("extensibility", "final")
        label = cls.__idl_typename__.replace(".", "::")  # type: ignore[attr-defined]
        ident = label.replace("::", "_")
        if any(other.ident == ident for other in self.models.values()):
            # Two IDL files may name a type alike (ShapeType: the Shapes Demo's in automotive.idl, the OMG suite's in
            # shape.idl): the generated functions of the later one carry its module too.
            ident = f"{ident}__{module_alias(class_module(cls))}"
        model = Model(cls, label, ident, extensibility == "appendable")
        try:
            if extensibility not in ("final", "appendable"):
                raise Unsupported(f"{extensibility} extensibility")
            if "keylist" in annotations:
                raise Unsupported("a keylist annotation")
            self.models[cls] = model  # before the members: a recursive type fails below, not here
            model.members = [(name, self.node(hint)) for name, hint in get_extended_type_hints(cls).items()]
            fields = [f.name for f in dataclasses.fields(cls)]
            if fields != [name for name, _ in model.members]:
                raise Unsupported(f"dataclass fields {fields} differ from the IDL members")
        except Unsupported as reason:
            self.models.pop(cls, None)
            self.unsupported[cls] = str(reason)
            raise
        return model

    def node(self, hint: Any) -> Node:
        if isinstance(hint, idl_types.typedef):
            return self.node(hint.subtype)
        if hint in PRIMITIVES:
            return Prim(*PRIMITIVES[hint])
        if inspect.isclass(hint) and issubclass(hint, Enum):
            if "bit_bound" in getattr(hint, "__idl_annotations__", {}):
                raise Unsupported("a bit-bound enum")
            return EnumNode(hint, repr(hint.__idl_enum_default_value__))  # type: ignore[attr-defined]
        if inspect.isclass(hint) and issubclass(hint, IdlStruct):
            return StructNode(self.model(hint))
        if hint is str:
            return Str(None)
        if isinstance(hint, idl_types.bounded_str):
            return Str(hint.max_length)
        if isinstance(hint, (idl_types.array, idl_types.sequence)):
            sub = self.node(hint.subtype)
            is_array = isinstance(hint, idl_types.array)
            length: int = hint.length if isinstance(hint, idl_types.array) else 0
            bound: int | None = hint.max_length if isinstance(hint, idl_types.sequence) else None
            if isinstance(sub, Prim) and sub.code == "B" and hint.subtype in (idl_types.uint8, idl_types.byte):
                return OctetArray(length) if is_array else OctetSeq(bound)
            if isinstance(sub, Prim):
                return PrimArray(sub, length) if is_array else PrimSeq(sub, bound)
            if isinstance(sub, StructNode):
                return StructArray(sub.model, length) if is_array else StructSeq(sub.model, bound)
            raise Unsupported(f"an array or sequence of {hint.subtype!r}")
        raise Unsupported(f"a member of type {hint!r}")


# --- alignment knowledge while generating -----------------------------------------------------------------------------

@dataclass(frozen=True)
class Align:
    """The body offset is known to be ``residue`` modulo ``modulus`` (a power of two) at this point of the code."""

    modulus: int
    residue: int = 0

    def advance(self, size: int) -> Align:
        return Align(self.modulus, (self.residue + size) % self.modulus)

    def after_multiple_of(self, unit: int) -> Align:
        """After an unknown number of ``unit``-byte items."""
        modulus = min(self.modulus, unit & -unit) if unit else self.modulus
        return Align(modulus, self.residue % modulus)

    def meet(self, other: Align) -> Align:
        """What is known in both cases."""
        modulus = min(self.modulus, other.modulus)
        while modulus > 1 and self.residue % modulus != other.residue % modulus:
            modulus //= 2
        return Align(modulus, self.residue % modulus)


def leaf_alignment(node: Node, align_max: int) -> int:
    """The largest alignment of the primitives of a fixed-size node."""
    if isinstance(node, Prim):
        return min(node.size, align_max)
    if isinstance(node, PrimArray):
        return min(node.prim.size, align_max)
    if isinstance(node, EnumNode):
        return 4
    if isinstance(node, OctetArray):
        return 1
    if isinstance(node, StructNode):
        return max((leaf_alignment(sub, align_max) for _, sub in node.model.members), default=1)
    raise AssertionError(node)


def is_fixed(node: Node, xcdr2: bool) -> bool:
    """Same size and layout whatever the value (no strings, sequences, DHEADERs)."""
    if isinstance(node, (Prim, EnumNode, OctetArray, PrimArray)):
        return True
    if isinstance(node, StructNode):
        return not (xcdr2 and node.model.appendable) and all(is_fixed(sub, xcdr2) for _, sub in node.model.members)
    return False


def has_octet_block(model: Model, seen: set[int] | None = None) -> bool:
    seen = seen if seen is not None else set()
    if id(model) in seen:
        return False
    seen.add(id(model))
    for _, node in model.members:
        if isinstance(node, (OctetArray, OctetSeq)):
            return True
        if isinstance(node, (StructNode, StructArray, StructSeq)) and has_octet_block(node.model, seen):
            return True
    return False


def defaults_to_xcdr2(model: Model, seen: set[int] | None = None) -> bool:
    """Cyclone's default representation: XCDR2 when the type or any type in it is appendable (or mutable)."""
    seen = seen if seen is not None else set()
    if id(model) in seen:
        return False
    seen.add(id(model))
    if model.appendable:
        return True
    return any(defaults_to_xcdr2(node.model, seen) for _, node in model.members
               if isinstance(node, (StructNode, StructArray, StructSeq)))


# --- code emission ---------------------------------------------------------------------------------------------------

class Shared:
    """What all functions of one endianness share: precompiled formats, enum tables, constants."""

    def __init__(self) -> None:
        self.formats: dict[str, str] = {}  # struct format (without byte order) -> name
        self.enums: dict[type, str] = {}
        self.dtypes: dict[tuple[str, bool], str] = {}  # (model ident, xcdr2) -> name
        self.dtype_lines: list[str] = []
        self.keys: dict[tuple[type, str], str] = {}  # (class, member) -> name of its EXTRA_BOUNDS key
        self.counter = 0

    def struct(self, fmt: str) -> str:
        if fmt not in self.formats:
            self.formats[fmt] = f"S{len(self.formats)}"
        return self.formats[fmt]

    def enum(self, cls: type) -> str:
        if cls not in self.enums:
            self.enums[cls] = f"ENUM_{cls.__idl_typename__.replace('.', '_')}"  # type: ignore[attr-defined]
        return self.enums[cls]

    def key(self, cls: type, member: str) -> str:
        if (cls, member) not in self.keys:
            self.keys[(cls, member)] = f"K{len(self.keys)}"
        return self.keys[(cls, member)]

    def tmp(self, stem: str = "t") -> str:
        self.counter += 1
        return f"{stem}{self.counter}"


def class_module(cls: type) -> str:
    """The module to import ``cls`` from: the IDL module's package when it exports it (idlc puts the classes in a
    submodule named after the IDL file), else the class's own module."""
    module = cls.__module__
    package = module.rpartition(".")[0]
    if package.count(".") > 1 and getattr(sys.modules.get(package), cls.__name__, None) is cls:
        return package
    return module


def class_ref(cls: type) -> str:
    return f"{module_alias(class_module(cls))}.{cls.__name__}"


def module_alias(module: str) -> str:
    return "m_" + module.removeprefix("automotive.types.").replace(".", "_")


class Emitter:
    def __init__(self, shared: Shared, xcdr2: bool, indent: int = 1):
        self.shared = shared
        self.xcdr2 = xcdr2
        self.align_max = 4 if xcdr2 else 8
        self.state = Align(self.align_max)
        self.lines: list[str] = []
        self.indent = indent
        self.fmt: list[str] = []  # the pending run of fixed-size fields
        self.fmt_size = 0

    def line(self, text: str) -> None:
        self.lines.append("    " * self.indent + text)

    def fork(self) -> Emitter:
        """A copy that emits into its own lines (for loop bodies tried with several alignment assumptions)."""
        other = copy.copy(self)
        other.lines = []
        other.fmt = []
        other.fmt_size = 0
        other.shared = copy.deepcopy(self.shared)
        return other

    def adopt(self, other: Emitter) -> None:
        self.lines.extend(other.lines)
        self.shared.__dict__.update(other.shared.__dict__)
        self.state = other.state

    def pad(self, count: int) -> None:
        self.fmt.append(f"{count}x")
        self.fmt_size += count
        self.state = self.state.advance(count)

    def align(self, alignment: int) -> None:
        alignment = min(alignment, self.align_max)
        if alignment <= 1:
            return
        if self.state.modulus >= alignment:
            padding = -self.state.residue % alignment
            if padding:
                self.pad(padding)
        else:
            self.runtime_align(alignment)
            self.state = Align(alignment)

    def runtime_align(self, alignment: int) -> None:
        raise NotImplementedError

    def loop(self, header: str, body: Any) -> None:
        """Emit ``header`` and an indented body made by ``body(emitter)``, valid whatever the iteration: the body is
        generated under the alignment known both on entry and after any number of iterations."""
        self.flush()
        assumed = self.state
        while True:
            trial = self.fork()
            trial.state = assumed
            trial.indent = self.indent + 1
            body(trial)
            trial.flush()
            known = assumed.meet(trial.state)
            if known == assumed:
                break
            assumed = known
        self.line(header)
        self.adopt(trial)
        self.state = assumed

    def flush(self) -> None:
        raise NotImplementedError


class EncodeEmitter(Emitter):
    """Builds ``buf`` (a bytearray holding the header and the body so far)."""

    def __init__(self, shared: Shared, xcdr2: bool, indent: int = 1):
        super().__init__(shared, xcdr2, indent)
        self.args: list[str] = []
        self.buf_made = True  # False for a top-level function until its first write

    def fork(self) -> EncodeEmitter:
        other = super().fork()
        assert isinstance(other, EncodeEmitter)
        other.args = []
        return other

    def write(self, code: str, size: int, expression: str) -> None:
        self.fmt.append(code)
        self.fmt_size += size
        self.args.append(expression)
        self.state = self.state.advance(size)

    def runtime_align(self, alignment: int) -> None:
        self.flush()
        self.line(f"buf += PADDING[(4 - len(buf)) & {alignment - 1}]")

    def flush(self) -> None:
        if not self.fmt:
            return
        if self.args:
            call = f"{self.shared.struct(''.join(self.fmt))}.pack({', '.join(self.args)})"
        else:
            call = f"PADDING[{self.fmt_size}]" if self.fmt_size < 8 else f"bytes({self.fmt_size})"
        if self.buf_made:
            self.line(f"buf += {call}")
        else:
            self.line(f"buf = bytearray({call})")
            self.buf_made = True
        self.fmt, self.args, self.fmt_size = [], [], 0

    def finish(self) -> None:
        """The return statement of a top-level encoder."""
        if not self.buf_made:  # one format for the whole sample
            call = f"{self.shared.struct(''.join(self.fmt))}.pack({', '.join(self.args)})"
            self.line(f"return {call}")
        else:
            self.flush()
            self.line("return bytes(buf)")

    def bound_checks(self, length: str, bound: int | None, model: Model, member: str, unit: str) -> None:
        label = f"{model.label}.{member}"
        if bound:
            self.line(f"if {length} > {bound}: raise OverBound({label!r}, {length}, {bound}, {unit!r})")
        if unit == "elements":  # automotive.bounds' extra bounds apply to sequences
            key = self.shared.key(model.cls, member)
            self.line(f"if {length} > EXTRA_BOUNDS.get({key}, {length}): "
                      f"raise OverBound({label!r}, {length}, EXTRA_BOUNDS[{key}], {unit!r})")

    def value(self, node: Node, expression: str, owner: Model, member: str) -> None:
        label = f"{owner.label}.{member}"
        if isinstance(node, Prim):
            self.align(node.size)
            self.write(node.code, node.size, expression)
        elif isinstance(node, EnumNode):
            name = self.shared.tmp("e")
            self.line(f"{name} = {expression}")
            self.align(4)
            self.write("I", 4, f"{name} if {name}.__class__ is int else {name}.value")
        elif isinstance(node, PrimArray):
            self.prim_array(node, expression)
        elif isinstance(node, Str):
            text, encoded = self.shared.tmp("s"), self.shared.tmp("b")
            self.line(f"{text} = {expression}")
            if node.bound:
                self.bound_checks(f"len({text})", node.bound, owner, member, "characters")
            self.line(f"{encoded} = {text}.encode()")
            self.align(4)
            self.write("I", 4, f"len({encoded}) + 1")
            self.flush()
            self.line(f"buf += {encoded}")
            self.line("buf.append(0)")
            self.state = Align(1)
        elif isinstance(node, OctetArray):
            block = self.shared.tmp("o")
            self.flush()
            self.line(f"{block} = octets({expression}, {label!r})")
            self.line(f"if len({block}) != {node.length}: raise CodecError(f'{label} holds {{len({block})}} bytes; "
                      f"the array has exactly {node.length}')")
            self.line(f"buf += {block}")
            self.state = self.state.advance(node.length)
        elif isinstance(node, OctetSeq):
            block, length = self.shared.tmp("o"), self.shared.tmp("n")
            self.line(f"{block} = octets({expression}, {label!r})")
            self.line(f"{length} = len({block})")
            self.bound_checks(length, node.bound, owner, member, "elements")
            self.align(4)
            self.write("I", 4, length)
            self.flush()
            self.line(f"buf += {block}")
            self.state = self.state.after_multiple_of(1)
        elif isinstance(node, PrimSeq):
            self.prim_seq(node, expression, owner, member)
        elif isinstance(node, StructNode):
            self.struct(node.model, expression)
        elif isinstance(node, (StructSeq, StructArray)):
            self.struct_sequence(node, expression, owner, member)
        else:
            raise AssertionError(node)

    def prim_array(self, node: PrimArray, expression: str) -> None:
        prim = node.prim
        self.align(prim.size)
        if node.length <= SMALL_ARRAY:
            names = [self.shared.tmp("a") for _ in range(node.length)]
            self.line(f"{', '.join(names)}, = {expression}")  # also checks the length, as Cyclone's assert does
            for name in names:
                self.write(prim.code, prim.size, name)
        else:
            self.flush()
            self.line(f"buf += {self.shared.struct(f'{node.length}{prim.code}')}.pack(*{expression})")
            self.state = self.state.advance(node.length * prim.size)

    def prim_seq(self, node: PrimSeq, expression: str, owner: Model, member: str) -> None:
        values, length = self.shared.tmp("q"), self.shared.tmp("n")
        self.line(f"{values} = {expression}")
        self.line(f"{length} = len({values})")
        self.bound_checks(length, node.bound, owner, member, "elements")
        self.align(4)
        self.write("I", 4, length)
        self.flush()
        empty = self.state
        size = node.prim.size
        self.line(f"if {length}:")
        if min(size, self.align_max) > 4:  # Cyclone aligns the elements only when there are some
            self.line(f"    buf += PADDING[(4 - len(buf)) & {min(size, self.align_max) - 1}]")
            filled = Align(self.align_max)
        else:
            filled = empty
        self.line(f"    buf += pack(E + str({length}) + {node.prim.code!r}, *{values})")
        self.state = empty.meet(filled.after_multiple_of(size))

    def struct(self, model: Model, expression: str) -> None:
        value = self.shared.tmp("v")
        self.line(f"{value} = {expression}")
        if self.xcdr2 and model.appendable:
            self.align(4)
            size = self.static_size(model)
            if size is not None:
                self.write("I", 4, str(size))
                self.members(model, value)
                return
            self.write("I", 4, "0")
            self.flush()
            start = self.shared.tmp("h")
            self.line(f"{start} = len(buf)")
            self.members(model, value)
            self.flush()
            self.line(f"U32.pack_into(buf, {start} - 4, len(buf) - {start})")
        else:
            self.members(model, value)

    def members(self, model: Model, value: str) -> None:
        for name, node in model.members:
            self.value(node, f"{value}.{name}", model, name)

    def static_size(self, model: Model) -> int | None:
        """The size of an appendable struct's members after its DHEADER when it is always the same."""
        if not all(is_fixed(node, self.xcdr2) for _, node in model.members):
            return None
        probe = DecodeEmitter(Shared(), self.xcdr2)
        probe.state = Align(4)
        for name, node in model.members:
            probe.value(node, model, name)
        return probe.fmt_size

    def struct_sequence(self, node: StructSeq | StructArray, expression: str, owner: Model, member: str) -> None:
        label = f"{owner.label}.{member}"
        values, length = self.shared.tmp("q"), self.shared.tmp("n")
        self.line(f"{values} = {expression}")
        self.line(f"{length} = len({values})")
        is_seq = isinstance(node, StructSeq)
        if isinstance(node, StructSeq):
            self.bound_checks(length, node.bound, owner, member, "elements")
        else:
            self.line(f"if {length} != {node.length}: raise CodecError(f'{label} holds {{{length}}} elements; "
                      f"the array has exactly {node.length}')")
        element = StructNode(node.model)
        bulk = bulk_layout(node.model, self.xcdr2)
        header_size = None
        if self.xcdr2:
            self.align(4)
            if bulk is not None and bulk[1] <= 4:  # no padding anywhere: the DHEADER is known from the length
                header_size = f"{4 if is_seq else 0} + {length} * {bulk[0]}"
                self.write("I", 4, header_size)
            else:
                self.write("I", 4, "0")
        if is_seq:
            self.align(4)
            self.write("I", 4, length)
        self.flush()
        start = None
        if self.xcdr2 and header_size is None:
            start = self.shared.tmp("h")  # where the DHEADER's count starts: right after it
            self.line(f"{start} = len(buf){' - 4' if is_seq else ''}")
        entry = self.state
        element_name = self.shared.tmp("x")
        if bulk is not None and bulk[1] <= 4 and entry.modulus >= bulk[1] and entry.residue % bulk[1] == 0:
            dtype = self.shared.dtypes_for(node.model, self.xcdr2)  # type: ignore[attr-defined]
            # A list (what Cyclone decodes and most programs build) skips the look for numpy at once.
            self.line(f"if {values}.__class__ is not list and is_array({values}):")
            self.line(f"    buf += struct_array_bytes({values}, {dtype}, {label!r})")
            self.line("else:")
            self.indent += 1
            self.loop(f"for {element_name} in {values}:",
                      lambda body: body.value(element, element_name, owner, member))
            self.indent -= 1
        else:
            self.loop(f"for {element_name} in {values}:",
                      lambda body: body.value(element, element_name, owner, member))
        if start is not None:
            self.line(f"U32.pack_into(buf, {start} - 4, len(buf) - {start})")


class DecodeEmitter(Emitter):
    """Reads ``data`` from ``pos`` (bytes-like; ``end`` is its length); each value is an expression over names."""

    def __init__(self, shared: Shared, xcdr2: bool, indent: int = 1):
        super().__init__(shared, xcdr2, indent)
        self.targets: list[str] = []

    def fork(self) -> DecodeEmitter:
        other = super().fork()
        assert isinstance(other, DecodeEmitter)
        other.targets = []
        return other

    def read(self, code: str, size: int) -> str:
        name = self.shared.tmp()
        self.fmt.append(code)
        self.fmt_size += size
        self.targets.append(name)
        self.state = self.state.advance(size)
        return name

    def runtime_align(self, alignment: int) -> None:
        self.flush()
        self.line(f"pos += (4 - pos) & {alignment - 1}")

    def flush(self) -> None:
        if not self.fmt:
            return
        if self.targets:
            self.line(f"{', '.join(self.targets)}, = {self.shared.struct(''.join(self.fmt))}.unpack_from(data, pos)")
        self.line(f"pos += {self.fmt_size}")
        self.fmt, self.targets, self.fmt_size = [], [], 0

    def value(self, node: Node, owner: Model, member: str) -> str:
        """Emit the reads of a value; return the expression that builds it."""
        label = f"{owner.label}.{member}"
        if isinstance(node, Prim):
            self.align(node.size)
            return self.read(node.code, node.size)
        if isinstance(node, EnumNode):
            self.align(4)
            name = self.read("I", 4)
            return f"{self.shared.enum(node.cls)}.get({name}, {name})"
        if isinstance(node, PrimArray):
            prim = node.prim
            self.align(prim.size)
            if node.length <= SMALL_ARRAY:
                return f"[{', '.join(self.read(prim.code, prim.size) for _ in range(node.length))}]"
            self.flush()
            name = self.shared.tmp()
            self.line(f"{name} = list({self.shared.struct(f'{node.length}{prim.code}')}.unpack_from(data, pos))")
            self.line(f"pos += {node.length * prim.size}")
            self.state = self.state.advance(node.length * prim.size)
            return name
        if isinstance(node, OctetArray):
            return self.read(f"{node.length}s", node.length)
        if isinstance(node, Str):
            self.align(4)
            length = self.read("I", 4)
            self.flush()
            text = self.shared.tmp("s")
            self.line(f"if not 0 < {length} <= end - pos: raise truncated({label!r}, {length}, pos, end)")
            self.line(f"if data[pos + {length} - 1]: raise CodecError(f'{label}: the string at byte {{pos}} does "
                      f"not end with a NUL')")
            self.line(f"{text} = str(data[pos:pos + {length} - 1], 'utf-8')")
            if node.bound:
                self.line(f"if len({text}) > {node.bound}: raise CodecError(f'{label}: {{len({text})}} characters, "
                          f"over its IDL bound of {node.bound}')")
            self.line(f"pos += {length}")
            self.state = Align(1)
            return text
        if isinstance(node, OctetSeq):
            self.align(4)
            length = self.read("I", 4)
            self.flush()
            block = self.shared.tmp("o")
            if node.bound:
                self.line(f"if {length} > {node.bound}: raise over_bound_read({label!r}, {length}, {node.bound})")
            self.line(f"if {length} > end - pos: raise truncated({label!r}, {length}, pos, end)")
            self.line(f"{block} = bytes(data[pos:pos + {length}])")
            self.line(f"pos += {length}")
            self.state = self.state.after_multiple_of(1)
            return block
        if isinstance(node, PrimSeq):
            return self.prim_seq(node, label)
        if isinstance(node, StructNode):
            return self.struct(node.model)
        if isinstance(node, (StructSeq, StructArray)):
            return self.struct_sequence(node, owner, member)
        raise AssertionError(node)

    def prim_seq(self, node: PrimSeq, label: str) -> str:
        self.align(4)
        length = self.read("I", 4)
        self.flush()
        if node.bound:
            self.line(f"if {length} > {node.bound}: raise over_bound_read({label!r}, {length}, {node.bound})")
        size = node.prim.size
        values = self.shared.tmp("q")
        self.line(f"if {length} * {size} > end - pos: raise truncated({label!r}, {length} * {size}, pos, end)")
        empty = self.state
        self.line(f"if {length}:")
        alignment = min(size, self.align_max)
        if alignment > 4:
            self.line(f"    pos += (4 - pos) & {alignment - 1}")
            filled = Align(self.align_max)
        else:
            filled = empty
        self.line(f"    {values} = list(unpack_from(E + str({length}) + {node.prim.code!r}, data, pos))")
        self.line(f"    pos += {length} * {size}")
        self.line("else:")
        self.line(f"    {values} = []")
        self.state = empty.meet(filled.after_multiple_of(size))
        return values

    def struct(self, model: Model) -> str:
        if self.xcdr2 and model.appendable:  # its own function: it reads its DHEADER and may be shorter or longer
            self.align(4)
            self.flush()
            name = self.shared.tmp("v")
            self.line(f"{name}, pos = d2_{model.ident}(data, pos, end, views)")
            self.state = Align(1)
            return name
        arguments = [self.value(node, model, member) for member, node in model.members]
        return f"{class_ref(model.cls)}({', '.join(arguments)})"

    def struct_sequence(self, node: StructSeq | StructArray, owner: Model, member: str) -> str:
        label = f"{owner.label}.{member}"
        is_seq = isinstance(node, StructSeq)
        header = None
        if self.xcdr2:
            self.align(4)
            header = self.read("I", 4)
        if isinstance(node, StructSeq):
            self.align(4)
            length = self.read("I", 4)
        else:
            length = str(node.length)
        self.flush()
        if isinstance(node, StructSeq) and node.bound:
            self.line(f"if {length} > {node.bound}: raise over_bound_read({label!r}, {length}, {node.bound})")
        header_end = None
        if header is not None:
            header_end = self.shared.tmp("h")
            self.line(f"{header_end} = pos + {header}{' - 4' if is_seq else ''}")
            self.line(f"if {header_end} > end: raise truncated({label!r}, {header}, pos, end)")
        values = self.shared.tmp("q")
        bulk = bulk_layout(node.model, self.xcdr2)
        entry = self.state
        if bulk is not None and entry.modulus >= bulk[1] and entry.residue % bulk[1] == 0:
            size = bulk[0]
            element = DecodeEmitter(self.shared, self.xcdr2)
            element.state = Align(bulk[1])
            build = element.struct(node.model)
            element_format = self.shared.struct("".join(element.fmt))
            count = self.shared.tmp("n")
            self.line(f"{count} = {length} * {size}")
            self.line(f"if {count} > end - pos: raise truncated({label!r}, {count}, pos, end)")
            dtype = self.shared.dtypes_for(node.model, self.xcdr2)  # type: ignore[attr-defined]
            self.line("if views:")
            self.line(f"    {values} = struct_array_view(data, {dtype}, {length}, pos)")
            self.line("else:")
            self.line(f"    {values} = [{build} for {', '.join(element.targets)}, in "
                      f"{element_format}.iter_unpack(data[pos:pos + {count}])]")
            self.line(f"pos += {count}")
            self.state = entry.after_multiple_of(size)
        else:
            self.line(f"if {length} > end - pos: raise truncated({label!r}, {length}, pos, end)")
            self.line(f"{values} = []")
            element_node = StructNode(node.model)

            def body(emitter: Emitter) -> None:
                assert isinstance(emitter, DecodeEmitter)
                built = emitter.value(element_node, owner, member)
                emitter.flush()
                emitter.line(f"{values}.append({built})")

            self.loop(f"for _ in range({length}):", body)
        if header_end is not None:
            self.line(f"if pos != {header_end}: raise CodecError(f'{label}: its DHEADER ends at byte {{{header_end}}}, "
                      f"its elements at {{pos}}')")
        return values


def bulk_layout(model: Model, xcdr2: bool) -> tuple[int, int] | None:
    """(size, alignment) of a struct whose elements can be packed and unpacked in bulk, else None: fixed size, and a
    size that is a multiple of its alignment (no padding between elements)."""
    node = StructNode(model)
    if not is_fixed(node, xcdr2):
        return None
    alignment = leaf_alignment(node, 4 if xcdr2 else 8)
    probe = DecodeEmitter(Shared(), xcdr2)
    probe.state = Align(alignment)
    probe.struct(model)
    if probe.fmt_size % alignment:
        return None
    return probe.fmt_size, alignment


def dtype_fields(model: Model, xcdr2: bool, offset: int, base: int) -> tuple[list[str], int]:
    """numpy dtype fields of a fixed-size struct laid out from ``offset`` (from the element's start; the element starts
    aligned), with offsets from ``base``; and the offset where it ends."""
    align_max = 4 if xcdr2 else 8
    entries = []
    for name, node in model.members:
        if isinstance(node, (Prim, EnumNode, PrimArray)):
            prim = Prim("I", 4) if isinstance(node, EnumNode) else node.prim if isinstance(node, PrimArray) else node
            alignment = min(prim.size, align_max)
            offset = -(-offset // alignment) * alignment
            code = f"{'E + ' if prim.size > 1 else ''}{NUMPY_CODES[prim.code]!r}"
            if isinstance(node, PrimArray):
                code = f"({code}, ({node.length},))"
                offset_after = offset + node.length * prim.size
            else:
                offset_after = offset + prim.size
            entries.append(f"({name!r}, {code}, {offset - base})")
            offset = offset_after
        elif isinstance(node, OctetArray):
            entries.append(f"({name!r}, ('u1', ({node.length},)), {offset - base})")
            offset += node.length
        elif isinstance(node, StructNode):
            inner, end = dtype_fields(node.model, xcdr2, offset, offset)
            entries.append(f"({name!r}, dtype_of([{', '.join(inner)}], {end - offset}), {offset - base})")
            offset = end
        else:
            raise AssertionError(node)
    return entries, offset


def _dtypes_for(self: Shared, model: Model, xcdr2: bool) -> str:
    key = (model.ident, xcdr2)
    if key not in self.dtypes:
        name = f"DT{2 if xcdr2 else 1}_{model.ident}"
        bulk = bulk_layout(model, xcdr2)
        assert bulk is not None
        entries, _ = dtype_fields(model, xcdr2, 0, 0)
        self.dtype_lines.append(f"{name} = LazyDtype(dtype_of([{', '.join(entries)}], {bulk[0]}))")
        self.dtypes[key] = name
    return self.dtypes[key]


Shared.dtypes_for = _dtypes_for  # type: ignore[attr-defined]


# --- whole functions -------------------------------------------------------------------------------------------------

def encoder(model: Model, xcdr2: bool, shared: Shared) -> list[str]:
    shared.counter = 0  # names are local to each function
    emitter = EncodeEmitter(shared, xcdr2)
    emitter.buf_made = False
    kind = ("H2A" if model.appendable else "H2F") if xcdr2 else "H1"
    emitter.fmt.append("4s")
    emitter.args.append(kind)  # the header is outside the body: the alignment state does not move
    emitter.fmt_size += 4
    emitter.struct(model, "sample")
    emitter.finish()
    return [f"def e{2 if xcdr2 else 1}_{model.ident}(sample):", *emitter.lines]


def decoders(model: Model, xcdr2: bool, shared: Shared) -> list[str]:
    shared.counter = 0
    name = f"d{2 if xcdr2 else 1}_{model.ident}"
    signature = "(data, pos, end, views)"
    if not (xcdr2 and model.appendable):
        emitter = DecodeEmitter(shared, xcdr2)
        emitter.state = Align(4 if xcdr2 and model.appendable else emitter.align_max)
        built = emitter.struct(model)
        emitter.flush()
        return [f"def {name}{signature}:", *emitter.lines, f"    return {built}, pos"]
    # XCDR2 appendable: its DHEADER, then the members; a different length means another version of the type
    fast = DecodeEmitter(shared, xcdr2, indent=2)
    fast.state = Align(4)
    arguments = [fast.value(node, model, member) for member, node in model.members]
    fast.flush()
    lines = [
        f"def {name}{signature}:",
        "    size, = U32.unpack_from(data, pos)",
        "    start = pos + 4",
        "    stop = start + size",
        f"    if stop > end: raise truncated({model.label!r}, size, start, end)",
        "    try:",
        "        pos = start",
        *fast.lines,
        "        if pos <= stop:",
        f"            return {class_ref(model.cls)}({', '.join(arguments)}), stop",
        "    except Exception:",
        "        pass",
        f"    return t2_{model.ident}(data, start, stop, end, views)",
        "",
        f"def t2_{model.ident}(data, start, stop, end, views):",
        f"    # {model.label} shorter than this version of it: the members past its end take their defaults",
        "    pos = start",
    ]
    tolerant = DecodeEmitter(shared, xcdr2, indent=2)
    tolerant.state = Align(4)
    names = []
    for member, node in model.members:
        tolerant.lines = []
        built = tolerant.value(node, model, member)
        tolerant.flush()
        value = shared.tmp("m")
        names.append(value)
        lines += ["    if pos < stop:", *tolerant.lines, f"        {value} = {built}",
                  f"        if pos > stop: raise CodecError(f'{model.label}.{member} ends at byte {{pos}}, past the "
                  f"end of its struct at {{stop}}')",
                  "    else:", f"        {value} = {default(node)}"]
    lines.append(f"    return {class_ref(model.cls)}({', '.join(names)}), stop")
    return lines


def default(node: Node) -> str:
    """Cyclone's default_initialize of a member (automotive.fastpath's for octet sequences: b'')."""
    if isinstance(node, Prim):
        return node.default
    if isinstance(node, EnumNode):
        return node.default
    if isinstance(node, Str):
        return "''"
    if isinstance(node, OctetArray):
        return f"bytearray({node.length})"
    if isinstance(node, OctetSeq):
        return "b''"
    if isinstance(node, PrimArray):
        return f"[{node.prim.default}] * {node.length}"
    if isinstance(node, (PrimSeq, StructSeq)):
        return "[]"
    if isinstance(node, StructNode):
        return f"{class_ref(node.model.cls)}({', '.join(default(sub) for _, sub in node.model.members)})"
    if isinstance(node, StructArray):
        return f"[{default(StructNode(node.model))} for _ in range({node.length})]"
    raise AssertionError(node)


# --- the module ------------------------------------------------------------------------------------------------------

PRELUDE = '''
class CodecError(ValueError):
    """Bytes that are not a valid serialized sample of the type, or a value a codec cannot encode."""


class OverBound(Exception):
    """Raised by the encoders when a sequence or string is longer than its bound (the registry makes a BoundError)."""

    def __init__(self, label, length, bound, unit):
        super().__init__(f"{label} holds {length} {unit}, over its IDL bound of {bound}")


# (type, member) -> bound for bounds the generated types leave out: automotive.cyclone.codecs binds it to
# automotive.cyclone.bounds.EXTRA_BOUNDS (the one registry of them) when it loads this module.
EXTRA_BOUNDS = {}
PADDING = tuple(bytes(n) for n in range(8))
_BYTE_FORMATS = ("B", "c")


def octets(value, label):
    """The bytes of an octet member as one buffer (bytes-like, or ints 0..255)."""
    if isinstance(value, (bytes, bytearray)):
        return value
    if isinstance(value, (int, str)):
        raise CodecError(f"{label}: expected bytes-like or a sequence of ints 0..255, got {type(value).__name__}")
    try:
        view = memoryview(value)
    except TypeError:
        view = None
    if view is not None and view.itemsize == 1 and view.format.lstrip("@=<>!") in _BYTE_FORMATS:
        if view.c_contiguous:
            return view if view.ndim == 1 and view.format == "B" else view.cast("B")
        return view.tobytes()
    try:
        return bytes(iter(value))
    except (TypeError, ValueError) as error:
        raise CodecError(f"{label}: expected bytes-like or a sequence of ints 0..255, got {type(value).__name__} "
                         f"({error})") from None


def numpy_if_loaded():
    """numpy's module if this process has imported it, else None. The codecs import numpy only to make a view: most
    programs never need it, and its import is about a sixth of a program's start-up. A process that has not imported
    numpy holds no numpy value, so this answers "is it numpy's?" without importing it."""
    return modules.get("numpy")


def is_array(value):
    numpy = numpy_if_loaded()
    return numpy is not None and value.__class__ is numpy.ndarray


class LazyDtype:
    """A numpy dtype given as its dict, made at its first use (see numpy_if_loaded)."""

    __slots__ = ("spec", "_dtype")

    def __init__(self, spec):
        self.spec = spec
        self._dtype = None

    def get(self):
        if self._dtype is None:
            from numpy import dtype

            self._dtype = dtype(self.spec)
        return self._dtype


def struct_array_bytes(value, lazy_dtype, label):
    """The CDR bytes of a numpy structured array for a sequence of fixed-size structs (converted to the wire dtype)."""
    dtype = lazy_dtype.get()
    if value.ndim != 1:
        raise CodecError(f"{label}: expected a 1-D structured array, got {value.ndim} dimensions")
    if value.dtype != dtype:
        if value.dtype.names != dtype.names:
            raise CodecError(f"{label}: expected a structured array with fields {dtype.names}, got {value.dtype.names}")
        value = value.astype(dtype)
    return value.tobytes()


def struct_array_view(data, lazy_dtype, count, offset):
    """``count`` elements of ``lazy_dtype`` at ``offset`` in ``data``, viewed (no copy) and read-only."""
    from numpy import frombuffer

    array = frombuffer(data, lazy_dtype.get(), count, offset)
    array.flags.writeable = False
    return array


def truncated(label, needed, pos, end):
    return CodecError(f"{label}: {needed} bytes announced at byte {pos} but only {max(end - pos, 0)} left")


def over_bound_read(label, length, bound):
    return CodecError(f"{label}: {length} elements announced, over its IDL bound of {bound}")
'''


def struct_types(package: str) -> Iterator[type]:
    """Every IdlStruct class defined in the modules of ``package``, module by module in name order, each module's in
    definition order."""
    root = importlib.import_module(package)
    modules = sorted(info.name for info in pkgutil.walk_packages(root.__path__, package + ".")
                     if not info.name.endswith((".codecs", ".typeinfo")))  # the generated modules beside them
    for module_name in modules:
        module = importlib.import_module(module_name)
        for value in vars(module).values():
            if inspect.isclass(value) and issubclass(value, IdlStruct) and value.__module__ == module_name:
                yield value


def generate(classes: list[type], header: str, source: str) -> str:
    models = Models()
    chosen: list[Model] = []
    skipped: list[str] = []
    for cls in classes:
        try:
            chosen.append(models.model(cls))
        except Unsupported as reason:
            skipped.append(f"{cls.__idl_typename__.replace('.', '::')}: {reason}")  # type: ignore[attr-defined]
    shared = Shared()
    functions: list[str] = []
    for model in chosen:
        for xcdr2 in (False, True):
            functions += encoder(model, xcdr2, shared) + [""]
            functions += decoders(model, xcdr2, shared) + [""]
    modules = sorted({class_module(cls) for cls in [m.cls for m in chosen] + list(shared.enums)})
    out = [f'"""{header}', "", f"Generated by automotive/cyclone/codecgen.py from {source}. Do not edit: run "
           "scripts/generate-types. automotive.cyclone.codecs makes Codec objects of CODEC_PARTS.", '"""', "",
           "# ruff: noqa", "", "from struct import Struct, pack, unpack_from", "from sys import modules", ""]
    out += [f"import {module} as {module_alias(module)}" for module in modules]
    out += ["", "", *PRELUDE.strip("\n").splitlines(), "", ""]
    if skipped:
        out += ["# No codec (Cyclone's serializer is used):", *[f"#   {line}" for line in skipped], ""]
    out += ["def dtype_of(fields, itemsize):",
            "    names, formats, offsets = zip(*fields) if fields else ((), (), ())",
            "    return {'names': list(names), 'formats': list(formats), 'offsets': list(offsets), "
            "'itemsize': itemsize}", "", ""]
    for cls, name in shared.enums.items():
        out.append(f"{name} = {{member.value: member for member in {class_ref(cls)}}}")
    out += [f"{name} = ({class_ref(cls)}, {member!r})" for (cls, member), name in shared.keys.items()]
    out += ["", "", "def build(E):", '    """Every encoder and decoder for one byte order (E: "<" or ">")."""',
            "    little = 1 if E == '<' else 0", "    H1 = bytes((0, little, 0, 0))",
            "    H2F = bytes((0, 6 | little, 0, 0))", "    H2A = bytes((0, 8 | little, 0, 0))",
            "    U32 = Struct(E + 'I')"]
    out += [f"    {name} = Struct(E + {fmt!r})" for fmt, name in shared.formats.items()]
    out += [f"    {line}" for line in shared.dtype_lines]
    out.append("")
    out += [f"    {line}" if line else "" for line in functions]
    out.append("    return locals()")
    out += ["", "", "LITTLE, BIG = build('<'), build('>')", "", "", "def _codec(cls, label, ident, default_xcdr2, "
            "octet_blocks, views):", "    encoders, decoders = {}, {}",
            "    for xcdr2 in (False, True):",
            "        for big, functions in ((False, LITTLE), (True, BIG)):",
            "            encoders[(xcdr2, big)] = functions[f'e{2 if xcdr2 else 1}_{ident}']",
            "            decoders[(xcdr2, big)] = functions[f'd{2 if xcdr2 else 1}_{ident}']",
            "    dtypes = {member: LITTLE[name] for member, name in views.items()}",
            "    return (label, default_xcdr2, encoders, decoders, dtypes, octet_blocks)", "", "",
            "CODEC_PARTS = {"]
    for model in chosen:
        views = {member: f"DT1_{node.model.ident}" for member, node in model.members
                 if isinstance(node, (StructSeq, StructArray)) and bulk_layout(node.model, False) is not None
                 and f"DT1_{node.model.ident}" in [n for n in shared.dtypes.values()]}
        out.append(f"    {class_ref(model.cls)}: _codec({class_ref(model.cls)}, {model.label!r}, {model.ident!r}, "
                   f"{defaults_to_xcdr2(model)}, {has_octet_block(model)}, {views!r}),")
    out += ["}", ""]
    return "\n".join(out)


def generated_types(prog: str, doc: str | None, argv: list[str] | None) -> list[type]:
    """The struct types of the folder a generator's command line names (TYPES_DIR, a fresh idlc output)."""
    parser = argparse.ArgumentParser(prog=prog, description=doc.splitlines()[0] if doc else None)
    parser.add_argument("types_dir", type=Path, help="the folder idlc generated automotive/types into")
    args = parser.parse_args(argv)
    import automotive.types

    # Import the types from the folder given, not the committed ones.
    automotive.types.__path__[:] = [str(args.types_dir.resolve())]
    return list(struct_types("automotive.types"))


def main(argv: list[str] | None = None) -> int:
    classes = generated_types("codecgen", __doc__, argv)
    text = generate(classes, "Fast CDR codecs for every struct type of the package's IDL.", "the generated types")
    sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
