"""Content filters: the SQL-like filter expressions of the DDS specification, applied on the reader's side.

    circles = ContentFilter.parse("color = %0 AND x BETWEEN 10 AND 200", ["'RED'"])
    matches = circles.bind(ShapeType)        # checks member names and types: a Predicate
    matches(sample)                          # True or False

The grammar is the one of DDS 1.4, annex B ("Syntax for Queries and Filters"), with the common extensions:

    Condition  ::= Predicate | Condition AND Condition | Condition OR Condition | NOT Condition | ( Condition )
    Predicate  ::= Operand RelOp Operand | Operand [NOT] LIKE Operand | Operand [NOT] BETWEEN Operand AND Operand
    RelOp      ::= = | <> | != | < | <= | > | >=
    Operand    ::= Member | number | 'string' | TRUE | FALSE | %n (parameter n, 0..99) | ENUMERATOR
    Member     ::= name ( .name | [index] )*          e.g. color, timestamp.s, objects[0].position

Keywords are case-insensitive. A parameter's text is itself a literal (``'RED'``, ``20``, ``CLASSIFICATION_CAR``);
a text that is none (``RED``) stands for that string, as some vendors pass strings without quotes. ``LIKE`` takes a
string pattern where ``%`` is any run of characters and ``_`` any one character. A comparison names at least one
member; two members may be compared with each other. A comparison of a member indexed past the end of its sequence is
unknown, as SQL's NULL: ``NOT`` keeps it unknown, ``unknown OR true`` is true, ``unknown AND false`` is false, and a
sample whose whole condition is unknown does not match (so neither ``objects[9].x = 1`` nor its ``NOT`` matches a
list of two objects). An expression nests at most 200 conditions deep (``a OR b OR ...`` of 200 terms).
Binding to a type rejects, with the position in the expression, a member the type does not have, a member that is a
struct or a sequence, and a literal of the wrong kind (``x = 'RED'`` for an int32 x).

Where it applies: :class:`FilteredReader` (a :class:`~automotive.bus.checkedreader.CheckedReader` whose ``take``
and ``read`` return only matching data: the filter sees only samples that decoded and passed their type's checks, so
a filtered reader still reports and leaves out bad samples) and automotive.wire.filteredraw.FilteredRawReader
(serialized samples, decoded and checked only to be tested). Both filter after Cyclone's reader cache, before the
application sees a sample: a KEEP_LAST history also keeps samples that do not match (DDS filters before the
history). A disposal or unregistration reaches the application only for instances it has seen data of, also when it
comes with a sample that does not match. A sample the filter cannot be evaluated on (a value no accessor expects from
another vendor's writer) is reported as a bad sample and left out; it never raises out of ``take``.
Sequences read as numpy views (``CheckedReader.use_views``) are filtered as well: their elements are numpy records.

The parsing is done by Lark (PyPI ``lark``, a well-kept parsing library) from the grammar below: no library parses
the DDS filter language itself. Evaluation is ours: the tree compiles to nested Python closures once, so a sample
costs a few attribute reads and comparisons (``automotive bench filter`` measures it).
"""

from __future__ import annotations

import enum
import functools
import importlib
import operator
import re
import typing
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from cyclonedds.core import InstanceState
from cyclonedds.idl import IdlEnum, IdlStruct, IdlUnion
from cyclonedds.idl import types as idl_types

from automotive.bus.badsamples import BadSample
from automotive.bus.checkedreader import CheckedReader, ended_instance
from automotive.bus.errors import ConfigError
from automotive.bus.properties import Properties
from automotive.cyclone.bounds import member_types
from automotive.cyclone.codecs import numpy_if_loaded

if TYPE_CHECKING:  # Lark itself is imported where an expression is parsed or bound: few programs are given a filter,
    # and importing it is about 40 ms of every program's start
    from lark import Lark, Token, Tree
    from lark.exceptions import UnexpectedInput

__all__ = ["ContentFilter", "FilterError", "FilteredReader", "Predicate", "SeenInstances", "TopicFilters", "evaluate"]

Predicate = Callable[[Any], bool]
# A condition before the last step of bind(): True, False or None (unknown: a member past the end of its sequence).
Condition = Callable[[Any], "bool | None"]
MAX_PARAMETERS = 100
MAX_DEPTH = 200  # nested conditions; a deeper tree would recurse past Python's limit when bound or evaluated

_GRAMMAR = r"""
condition: disjunction
?disjunction: conjunction | disjunction _OR conjunction -> or_
?conjunction: negation | conjunction _AND negation -> and_
?negation: _NOT negation -> not_ | "(" disjunction ")" | predicate
?predicate: operand RELOP operand -> compare
          | operand _LIKE operand -> like
          | operand _NOT _LIKE operand -> not_like
          | operand _BETWEEN operand _AND operand -> between
          | operand _NOT _BETWEEN operand _AND operand -> not_between
?operand: member | NUMBER | STRING | PARAMETER | TRUE | FALSE
member: NAME (_DOT NAME | "[" INDEX "]")*
literal: NUMBER | STRING | TRUE | FALSE | NAME

_OR.2: /or\b/i
_AND.2: /and\b/i
_NOT.2: /not\b/i
_LIKE.2: /like\b/i
_BETWEEN.2: /between\b/i
TRUE.2: /true\b/i
FALSE.2: /false\b/i
RELOP: "<>" | "!=" | "<=" | ">=" | "=" | "<" | ">"
NAME: /[A-Za-z_][A-Za-z0-9_]*/
_DOT: "."
INDEX: /[0-9]+/
NUMBER: /[+-]?(0[xX][0-9a-fA-F]+|([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?)/
STRING: /'[^']*'|"[^"]*"/
PARAMETER: /%[0-9]{1,2}/
%ignore /[ \t\r\n]+/
"""


@functools.cache
def _parser() -> Lark:
    """The grammar's parser, built on first use: building it is most of this module's import time (about 0.1 s),
    which every program would pay at start, though few are given a filter."""
    from lark import Lark

    return Lark(_GRAMMAR, start=["condition", "literal"], parser="lalr", maybe_placeholders=False)


_COMPARISONS: dict[str, Callable[[Any, Any], bool]] = {
    "=": operator.eq, "<>": operator.ne, "!=": operator.ne, "<": operator.lt, "<=": operator.le, ">": operator.gt,
    ">=": operator.ge,
}
_MIRRORED = {"<": ">", "<=": ">=", ">": "<", ">=": "<=", "=": "=", "<>": "<>", "!=": "!="}
_TERMINAL_NAMES = {
    "_OR": "OR", "_AND": "AND", "_NOT": "NOT", "_LIKE": "LIKE", "_BETWEEN": "BETWEEN", "TRUE": "TRUE",
    "FALSE": "FALSE", "RELOP": "a comparison (=, <>, <, <=, >, >=)", "NAME": "a member name", "NUMBER": "a number",
    "STRING": "a 'string'", "PARAMETER": "a parameter %n", "LPAR": "(", "RPAR": ")", "INDEX": "an index",
    "_DOT": ".", "LSQB": "[", "RSQB": "]", "$END": "the end",
}


class FilterError(ValueError):
    """A filter expression that does not parse or does not fit the type; ``position`` is 1-based (0: none)."""

    def __init__(self, message: str, position: int = 0):
        super().__init__(f"position {position}: {message}" if position else message)
        self.position = position


# -- what a member holds ---------------------------------------------------------------------------------------------
class Kind(enum.Enum):
    NUMBER = "a number"
    STRING = "a string"
    BOOLEAN = "a boolean"
    ENUM = "an enumeration"
    STRUCT = "a struct"
    SEQUENCE = "a sequence"
    OTHER = "a value of another kind"


@dataclass(frozen=True)
class MemberType:
    kind: Kind
    python_type: Any = None  # the struct or enum class; the element type of a sequence or array
    name: str = ""  # as the IDL spells it, for messages


def _resolved(hint: Any) -> Any:
    """A forward reference of the generated code ('automotive.types.Vision.VisionObject', as a sequence's element
    type) as its class; Cyclone's own resolver does this, the public fallback of member_types does not."""
    if not isinstance(hint, str) or "." not in hint:
        return hint
    module, _, name = hint.rpartition(".")
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError):
        return hint


def _member_type(hint: Any) -> MemberType:
    hint = _resolved(hint)
    if isinstance(hint, idl_types.typedef):
        return _member_type(hint.subtype)
    if isinstance(hint, (idl_types.sequence, idl_types.array)):
        return MemberType(Kind.SEQUENCE, hint.subtype, repr(hint))
    if isinstance(hint, idl_types.bounded_str):
        return MemberType(Kind.STRING, str, repr(hint))
    if typing.get_origin(hint) is typing.Annotated:
        base, *annotations = typing.get_args(hint)
        name = str(annotations[0]) if annotations else ""
        for annotation in annotations:  # arrays and sequences hide inside Annotated
            if isinstance(annotation, (idl_types.sequence, idl_types.array, idl_types.typedef)):
                return _member_type(annotation)
        if base is str:
            return MemberType(Kind.STRING, str, name)
        if base in (int, float):
            return MemberType(Kind.NUMBER, base, name)
        return _member_type(base)
    if hint is bool:
        return MemberType(Kind.BOOLEAN, bool, "boolean")
    if hint in (int, float):
        return MemberType(Kind.NUMBER, hint, hint.__name__)
    if hint is str:
        return MemberType(Kind.STRING, str, "string")
    if isinstance(hint, type) and issubclass(hint, IdlEnum):
        return MemberType(Kind.ENUM, hint, hint.__name__)
    if isinstance(hint, type) and issubclass(hint, (IdlStruct, IdlUnion)):
        return MemberType(Kind.STRUCT, hint, hint.__name__)
    return MemberType(Kind.OTHER, hint, repr(hint))


# -- operands after binding ------------------------------------------------------------------------------------------
class _Missing(Exception):
    """A member indexed past the end of its sequence: the predicate that reads it is false."""


@dataclass
class _Operand:
    position: int
    text: str
    member: MemberType | None = None  # set for a member
    read: Callable[[Any], Any] | None = None  # reads the member from a sample (enums as their integer value)
    value: Any = None  # a constant's value
    kind: Kind | None = None  # a constant's kind (NAME: an unresolved enumerator, resolved against the member)
    enumerator: str = ""  # a bare name that is no member: an enumerator, once the other side says of which enum

    @property
    def is_member(self) -> bool:
        return self.read is not None


def _accessor(steps: list[str | int]) -> Callable[[Any], Any]:
    if all(isinstance(step, str) for step in steps):
        return operator.attrgetter(".".join(str(step) for step in steps))

    def read(sample: Any) -> Any:
        value = sample
        for step in steps:
            if isinstance(step, str):
                # An element of a numpy view is a record: its fields are items (as attributes, some would be numpy's
                # own: a record's .size is 1, not the member size).
                numpy = numpy_if_loaded()
                value = value[step] if numpy is not None and isinstance(value, numpy.void) else getattr(value, step)
            else:
                try:
                    value = value[step]
                except IndexError:
                    raise _Missing from None
        return value

    return read


def _enum_reader(read: Callable[[Any], Any]) -> Callable[[Any], Any]:
    """An enum member as its integer value. A value outside the enum (another vendor's writer may send one) decodes
    as a plain int, and a numpy view holds plain ints: both are their own value."""

    def read_value(sample: Any) -> Any:
        value = read(sample)
        return getattr(value, "value", value)

    return read_value


class ContentFilter:
    """A parsed filter expression with its parameters; :meth:`bind` makes a predicate for one type."""

    def __init__(self, expression: str, tree: Tree[Token], parameters: Sequence[str]):
        self.expression = expression
        self.tree = tree
        self.parameters = list(parameters)

    @classmethod
    def parse(cls, expression: str, parameters: Sequence[str] = ()) -> ContentFilter:
        """Parse ``expression``; raises :class:`FilterError` naming the position of the first error."""
        if not expression.strip():
            raise FilterError("the expression is empty", 1)
        if len(parameters) > MAX_PARAMETERS:
            raise FilterError(f"{len(parameters)} parameters given, at most {MAX_PARAMETERS} (%0..%99)")
        from lark import Token
        from lark.exceptions import UnexpectedInput

        try:
            tree = _parser().parse(expression, start="condition")
        except UnexpectedInput as error:
            raise _syntax_error(expression, error) from None
        _check_depth(tree)
        used = sorted({int(token[1:]) for token in tree.scan_values(
            lambda t: isinstance(t, Token) and t.type == "PARAMETER")})
        for number in used:
            if number >= len(parameters):
                token = next(t for t in tree.scan_values(lambda t: isinstance(t, Token) and t.type == "PARAMETER")
                             if int(t[1:]) == number)
                raise FilterError(f"parameter %{number} is used but {len(parameters)} parameter(s) given",
                                  _position(token))
        return cls(expression, tree, parameters)

    def bind(self, data_type: type[Any]) -> Predicate:
        """A predicate for samples of ``data_type``; raises :class:`FilterError` for members the type does not have
        or literals of the wrong kind."""
        condition = _Binder(data_type, self.parameters).condition(self.tree.children[0])
        return lambda sample: condition(sample) is True  # unknown does not match

    def __repr__(self) -> str:
        return f"ContentFilter({self.expression!r}, {self.parameters!r})"


def _check_depth(tree: Tree[Token]) -> None:
    """Refuse a tree deeper than MAX_DEPTH conditions; walked with a list, as recursion is what it guards against."""
    from lark import Tree

    pending: list[tuple[Tree[Token], int]] = [(tree, 0)]
    while pending:
        node, depth = pending.pop()
        if node.data in ("or_", "and_", "not_"):
            depth += 1
            if depth > MAX_DEPTH:
                raise FilterError(f"the expression nests more than {MAX_DEPTH} conditions deep (AND, OR, NOT): "
                                  "split it or use BETWEEN")
        pending.extend((child, depth) for child in node.children if isinstance(child, Tree))


def _position(token: Token) -> int:
    return int(token.start_pos or 0) + 1


def _syntax_error(expression: str, error: UnexpectedInput) -> FilterError:
    from lark.exceptions import UnexpectedCharacters, UnexpectedEOF, UnexpectedToken

    if isinstance(error, UnexpectedEOF):
        return FilterError("the expression ends too early", len(expression) + 1)
    position = int(getattr(error, "pos_in_stream", 0) or 0) + 1
    if isinstance(error, UnexpectedCharacters):
        return FilterError(f"unexpected character {expression[position - 1]!r}", position)
    if isinstance(error, UnexpectedToken):
        token = error.token
        if token.type == "$END":
            return FilterError("the expression ends too early", len(expression) + 1)
        expected = sorted({_TERMINAL_NAMES.get(name, name) for name in error.expected})
        position = _position(token)
        return FilterError(f"unexpected {str(token)!r} (expected {' or '.join(expected)})", position)
    return FilterError(str(error).splitlines()[0], position)  # pragma: no cover - lark's other errors


def _parse_literal(text: str) -> Token | None:
    """A parameter's text as a literal token, or None when it is none (then it stands for that string)."""
    from lark import Token
    from lark.exceptions import UnexpectedInput

    try:
        tree = _parser().parse(text, start="literal")
    except UnexpectedInput:
        return None
    token = tree.children[0]
    return token if isinstance(token, Token) else None


def _number(text: str, position: int) -> int | float:
    lowered = text.lower()
    try:
        if "0x" in lowered:
            return int(lowered, 16)
        if any(mark in lowered for mark in ".e"):
            return float(text)
        return int(text)
    except ValueError:  # Python refuses to convert integers of more than 4,300 digits
        raise FilterError(f"the number {text[:20]}... has {len(text)} digits: far more than any member holds",
                          position) from None


class _Binder:
    """Compiles a parse tree into closures for one data type."""

    def __init__(self, data_type: type[Any], parameters: list[str]):
        self.data_type = data_type
        self.parameters = parameters

    # -- conditions
    def condition(self, node: Tree[Token] | Token) -> Condition:
        from lark import Tree

        if not isinstance(node, Tree):  # pragma: no cover - the grammar makes every condition a tree
            raise FilterError(f"{node!r} is not a condition", _position(node))
        rule = node.data
        # SQL's three-valued logic: None is unknown (a member past the end of its sequence), see the module's doc.
        if rule == "or_":
            left, right = (self.condition(child) for child in node.children)

            def either(sample: Any) -> bool | None:
                first = left(sample)
                if first:
                    return True
                second = right(sample)
                return True if second else None if first is None or second is None else False

            return either
        if rule == "and_":
            left, right = (self.condition(child) for child in node.children)

            def both(sample: Any) -> bool | None:
                first = left(sample)
                if first is False:
                    return False
                second = right(sample)
                return False if second is False else None if first is None or second is None else True

            return both
        if rule == "not_":
            inner = self.condition(node.children[0])

            def negated(sample: Any) -> bool | None:
                value = inner(sample)
                return None if value is None else not value

            return negated
        if rule == "compare":
            return self.compare(node)
        if rule in ("like", "not_like"):
            return self.like(node, negate=rule == "not_like")
        if rule in ("between", "not_between"):
            return self.between(node, negate=rule == "not_between")
        if rule == "condition":
            return self.condition(node.children[0])
        position = _first_position(node)
        raise FilterError("a member alone is not a condition (compare it: member = value)", position)

    def compare(self, node: Tree[Token]) -> Condition:
        from lark import Tree

        left_node, relop, right_node = node.children
        left, right = self.operand(left_node), self.operand(right_node)
        op_text = str(relop)
        for side in (left, right):
            if side.enumerator and not left.is_member and not right.is_member:
                raise FilterError(f"{self.data_type.__name__} has no member {side.enumerator!r}", side.position)
        if not left.is_member and not right.is_member:
            raise FilterError(f"'{left.text} {op_text} {right.text}' compares two constants: name a member",
                              left.position)
        if not left.is_member:  # constant op member: turn it round
            left, right, op_text = right, left, _MIRRORED[op_text]
        self.check_comparable(left, right, op_text)
        compare = _COMPARISONS[op_text]
        read_left = left.read
        assert read_left is not None
        guarded = any(isinstance(step, int) for step in _steps_of(left_node)) or \
            (isinstance(right_node, Tree) and any(isinstance(step, int) for step in _steps_of(right_node)))
        if right.is_member:
            read_right = right.read
            assert read_right is not None
            predicate: Predicate = lambda sample: compare(read_left(sample), read_right(sample))  # noqa: E731
        else:
            constant = right.value
            predicate = lambda sample: compare(read_left(sample), constant)  # noqa: E731
        return _guard(predicate) if guarded else predicate

    def like(self, node: Tree[Token], negate: bool) -> Condition:
        subject_node, pattern_node = node.children
        subject, pattern = self.operand(subject_node), self.operand(pattern_node)
        if not subject.is_member or subject.member is None or subject.member.kind is not Kind.STRING:
            raise FilterError(f"LIKE needs a string member on its left, not {subject.text!r}", subject.position)
        if pattern.is_member or pattern.kind is not Kind.STRING:
            raise FilterError(f"LIKE needs a 'pattern' string on its right, not {pattern.text!r}", pattern.position)
        regex = re.compile("".join(".*" if c == "%" else "." if c == "_" else re.escape(c) for c in pattern.value),
                           re.DOTALL)
        read = subject.read
        assert read is not None
        if negate:
            return _guard(lambda sample: regex.fullmatch(read(sample)) is None)
        return _guard(lambda sample: regex.fullmatch(read(sample)) is not None)

    def between(self, node: Tree[Token], negate: bool) -> Condition:
        subject_node, low_node, high_node = node.children
        subject, low, high = (self.operand(child) for child in (subject_node, low_node, high_node))
        if not subject.is_member:
            raise FilterError(f"BETWEEN needs a member on its left, not {subject.text!r}", subject.position)
        for bound in (low, high):
            if bound.is_member:
                raise FilterError(f"BETWEEN needs constants as bounds, not the member {bound.text!r}",
                                  bound.position)
            self.check_comparable(subject, bound, "BETWEEN")
        read, low_value, high_value = subject.read, low.value, high.value
        assert read is not None
        if negate:
            return _guard(lambda sample: not low_value <= read(sample) <= high_value)
        return _guard(lambda sample: low_value <= read(sample) <= high_value)

    # -- operands
    def operand(self, node: Tree[Token] | Token) -> _Operand:
        from lark import Tree

        if isinstance(node, Tree):  # a member (or an enumerator: a bare name that is no member)
            return self.member(node)
        position = _position(node)
        if node.type == "PARAMETER":
            text = self.parameters[int(node[1:])]
            token = _parse_literal(text)
            if token is None or token.type == "NAME":  # not a literal, or a bare name: that string (or enumerator)
                return _Operand(position, f"{node} ({text})", value=text, kind=Kind.STRING)
            constant = self.constant(token, position)
            constant.text = f"{node} ({text})"
            return constant
        return self.constant(node, position)

    def constant(self, token: Token, position: int) -> _Operand:
        text = str(token)
        if token.type == "NUMBER":
            return _Operand(position, text, value=_number(text, position), kind=Kind.NUMBER)
        if token.type == "STRING":
            return _Operand(position, text, value=text[1:-1], kind=Kind.STRING)
        if token.type in ("TRUE", "FALSE"):
            return _Operand(position, text, value=token.type == "TRUE", kind=Kind.BOOLEAN)
        return _Operand(position, text, enumerator=text)  # NAME in a parameter: an enumerator

    def member(self, node: Tree[Token]) -> _Operand:
        steps = _steps_of(node)
        position = _first_position(node)
        text = _member_text(steps)
        owner: Any = self.data_type
        member_type = MemberType(Kind.STRUCT, self.data_type, self.data_type.__name__)
        walked = ""
        for step in steps:
            if isinstance(step, int):
                if member_type.kind is not Kind.SEQUENCE:
                    raise FilterError(f"{walked} is {member_type.kind.value}, it has no [index]", position)
                member_type = _member_type(member_type.python_type)
                walked += f"[{step}]"
                continue
            if member_type.kind is not Kind.STRUCT:
                if not walked and len(steps) == 1:
                    break  # pragma: no cover - the type itself is a struct
                raise FilterError(f"{walked} is {member_type.kind.value}, it has no member {step!r}", position)
            owner = member_type.python_type
            hints = member_types(owner)
            if step not in hints:
                if len(steps) == 1:  # a bare name: maybe an enumerator, resolved against the other side
                    return _Operand(position, text, enumerator=step)
                raise FilterError(f"{owner.__name__} has no member {step!r} (its members: {', '.join(hints)})",
                                  position)
            member_type = _member_type(hints[step])
            walked = f"{walked}.{step}" if walked else step
        if member_type.kind in (Kind.STRUCT, Kind.SEQUENCE, Kind.OTHER):
            raise FilterError(f"{text} is {member_type.kind.value} ({member_type.name}): compare its members or "
                              "elements", position)
        read = _accessor(steps)
        if member_type.kind is Kind.ENUM:
            read = _enum_reader(read)
        return _Operand(position, text, member=member_type, read=read)

    def check_comparable(self, member: _Operand, other: _Operand, op_text: str) -> None:
        """Both sides of one comparison hold the same kind of value; an enumerator name becomes its value."""
        assert member.member is not None
        kind = member.member.kind
        if other.enumerator and not other.is_member:
            if kind is Kind.ENUM:
                other.value, other.kind = self.enumerator(member, other), Kind.ENUM
            elif kind is Kind.STRING:
                raise FilterError(f"{self.data_type.__name__} has no member {other.enumerator!r} (a string needs "
                                  f"quotes: '{other.enumerator}')", other.position)
            else:
                raise FilterError(f"{self.data_type.__name__} has no member {other.enumerator!r}", other.position)
        other_kind = other.member.kind if other.member is not None else other.kind
        if kind is Kind.ENUM:
            if other_kind is Kind.NUMBER and isinstance(other.value, int) or other_kind is Kind.ENUM:
                return
            if other_kind is Kind.STRING and not other.is_member:  # 'CLASSIFICATION_CAR' quoted: allowed
                other.enumerator = str(other.value)
                other.value, other.kind = self.enumerator(member, other), Kind.ENUM
                return
        elif kind is other_kind:
            return
        described = other.member.kind.value if other.member is not None else (other.kind or Kind.OTHER).value
        raise FilterError(f"{member.text} is {kind.value} ({member.member.name}) but {other.text} is {described}",
                          other.position)

    def enumerator(self, member: _Operand, other: _Operand) -> int:
        assert member.member is not None
        enum_type = member.member.python_type
        names = {item.name.upper(): item.value for item in enum_type}
        # IDL enumerators may be scoped (Common::CLASSIFICATION_CAR); the last part names it.
        name = other.enumerator.rsplit("::", 1)[-1].upper()
        if name not in names:
            raise FilterError(f"{other.enumerator!r} is not an enumerator of {enum_type.__name__} "
                              f"({', '.join(item.name for item in enum_type)})", other.position)
        return int(names[name])


def _steps_of(node: Tree[Token] | Token) -> list[str | int]:
    from lark import Token, Tree

    if not isinstance(node, Tree):
        return []
    return [int(child) if child.type == "INDEX" else str(child) for child in node.children if isinstance(child, Token)]


def _member_text(steps: list[str | int]) -> str:
    text = ""
    for step in steps:
        text += f"[{step}]" if isinstance(step, int) else (f".{step}" if text else step)
    return text


def _first_position(node: Tree[Token]) -> int:
    """The position of the node's first token: its leftmost leaf (a loop: the tree may be deep)."""
    from lark import Token

    while node.children:
        first = node.children[0]
        if isinstance(first, Token):
            return _position(first)
        node = first
    return 0  # pragma: no cover - every member has a name


def _guard(predicate: Predicate) -> Condition:
    """A condition that is unknown (None) for a member indexed past the end of its sequence (or a None string)."""

    def guarded(sample: Any) -> bool | None:
        try:
            return bool(predicate(sample))  # a numpy view's values compare to numpy booleans: made Python's
        except (_Missing, TypeError):
            return None

    return guarded


def evaluate(predicate: Predicate, sample: Any) -> bool | BadSample:
    """Whether ``sample`` matches; a :class:`BadSample` when the filter cannot be evaluated on it at all (a value of
    a kind no member of the type holds), which the reader reports and leaves out: a filter never ends a take."""
    try:
        return bool(predicate(sample))
    except Exception as error:  # whatever an accessor or comparison raises on another system's odd value
        return BadSample("", f"the filter cannot be evaluated on it ({type(error).__name__}: {error})",
                         "a sample the content filter can test")


# -- readers -----------------------------------------------------------------------------------------------------------
_GONE = (InstanceState.NotAliveDisposed, InstanceState.NotAliveNoWriters)


class SeenInstances:
    """The instances a filtered reader has delivered data of: only their disposals and unregistrations pass."""

    def __init__(self) -> None:
        self.handles: set[int] = set()

    def data(self, instance: int, passed: bool, instance_state: int) -> bool:
        """Note a sample of data; True when it did not pass but says that an instance the application has seen
        ended: that end must reach the application, without the data."""
        if instance_state in _GONE:
            seen = instance in self.handles
            self.handles.discard(instance)
            return seen and not passed
        if passed:
            self.handles.add(instance)
        return False

    def state_change(self, instance: int) -> bool:
        """True when the application has seen data of ``instance`` (which is then forgotten)."""
        if instance in self.handles:
            self.handles.discard(instance)
            return True
        return False


class FilteredReader(CheckedReader[Any]):
    """A :class:`CheckedReader` whose ``take`` and ``read`` return only the samples that match its filter.

    The checked take comes first: samples that do not decode or fail their type's checks are reported and left out
    before the filter sees them. A call returns up to ``N`` matching samples, fewer when no more are available (it
    takes again while whole batches went by without enough matches, until it has looked at MAX_EXAMINED samples: a
    writer faster than the reader never keeps one call going). Samples that do not match are taken (or read) and
    dropped; when such a sample also says that an instance the application has seen ended, that end is passed on as a
    sample without data.
    """

    MAX_EXAMINED = 4096

    def __init__(self, *args: Any, content_filter: Predicate, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.content_filter = content_filter
        self.filtered_out = 0  # samples of data that did not match
        self._seen = SeenInstances()

    def _keep(self, samples: list[Any]) -> list[Any]:
        kept = []
        for sample in samples:
            info = sample.sample_info
            if info.valid_data:  # (the end of an instance whose last sample was bad comes without data)
                verdict = evaluate(self.content_filter, sample)
                if isinstance(verdict, BadSample):
                    self.report(verdict, info)
                    verdict = False
                else:
                    self.filtered_out += not verdict
                if self._seen.data(info.instance_handle, verdict, info.instance_state):
                    kept.append(ended_instance(sample, info))
                elif verdict:
                    kept.append(sample)
            elif self._seen.state_change(info.instance_handle):
                kept.append(sample)
        return kept

    def take(self, N: int = 1, condition: Any = None, instance_handle: int | None = None) -> list[Any]:
        kept: list[Any] = []
        examined = 0
        while True:
            wanted = N - len(kept)
            batch = super().take(wanted, condition, instance_handle)
            kept.extend(self._keep(batch))
            examined += len(batch)
            if len(batch) < wanted or len(kept) >= N or examined >= max(N, self.MAX_EXAMINED):
                return kept

    def read(self, N: int = 1, condition: Any = None, instance_handle: int | None = None) -> list[Any]:
        # read leaves samples in the reader: one call, as many as it returns (a second one would read the same).
        return self._keep(super().read(N, condition, instance_handle))


# -- per-topic filters of an application -------------------------------------------------------------------------------
FILTER_PREFIX = "config.filter."


@dataclass
class TopicFilter:
    topic: str
    expression: ContentFilter
    origin: str  # where it was given, for messages: "--filter Circle" or "<file>: config.filter.Circle"
    used: bool = False


class TopicFilters:
    """The content filters of an application's readers, one per topic: ``config.filter.<Topic>=EXPR`` in its
    properties and ``--filter TOPIC=EXPR`` on its command line (which wins for the same topic).

    A bad expression, an expression that does not fit the topic's type, and a filter for a topic the application
    does not read are :class:`ConfigError` s naming the option or key, the position and the expression.
    """

    def __init__(self, props: Properties, command_line: Sequence[str] = ()):
        self.filters: dict[str, TopicFilter] = {}
        for key in props.keys(FILTER_PREFIX):
            topic = key[len(FILTER_PREFIX):]
            self._add(topic, props.get_str(key), f"{props.where(key)}: {key}")
        for item in command_line:
            topic, separator, text = item.partition("=")
            if not separator or not topic.strip():
                raise ConfigError(f"--filter {item!r}: expected TOPIC=EXPRESSION, e.g. --filter \"Circle=x > 100\"")
            self._add(topic.strip(), text, f"--filter {topic.strip()}")

    def _add(self, topic: str, text: str, origin: str) -> None:
        if not topic:
            raise ConfigError(f"{origin}: expected {FILTER_PREFIX}<Topic>=EXPRESSION")
        try:
            self.filters[topic] = TopicFilter(topic, ContentFilter.parse(text), origin)
        except FilterError as error:
            raise ConfigError(f"{origin}: {error} in {text!r}") from None

    def predicate(self, topic: str, data_type: type[Any]) -> Predicate | None:
        """The bound filter of ``topic``'s readers, or None when it has none."""
        entry = self.filters.get(topic)
        if entry is None:
            return None
        entry.used = True
        try:
            return entry.expression.bind(data_type)
        except FilterError as error:
            raise ConfigError(f"{entry.origin}: {error} in {entry.expression.expression!r} "
                              f"(topic {topic}, type {data_type.__name__})") from None

    def check_all_used(self, app_name: str, topics_read: Sequence[str]) -> None:
        for entry in self.filters.values():
            if not entry.used:
                read = ", ".join(dict.fromkeys(topics_read)) or "none"
                raise ConfigError(f"{entry.origin}: {app_name} reads no topic '{entry.topic}' (it reads: {read})")

    def __bool__(self) -> bool:
        return bool(self.filters)
