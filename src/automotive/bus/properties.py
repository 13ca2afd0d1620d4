"""Java ``.properties`` files with typed getters.

The syntax is java.util.Properties' own, parsed by the ``javaproperties`` library: ``key=value``, ``key: value`` or
``key value``; ``#`` and ``!`` start comment lines; a line ending in a backslash continues on the next line;
``\\uXXXX``, ``\\t``, ``\\n``, ``\\=``, ``\\:`` and ``\\ `` are escapes. Values are also trimmed at the end (Java keeps
trailing blanks, which in a hand-edited file are always a mistake).

A program declares the keys it reads (:class:`PropertyKeys`); :meth:`Properties.declare` then refuses, before the
program does anything, a key of the file or of the overrides that it does not know, naming the nearest known key, and
notes every read of a key the declaration lacks (a defect of the declaration, which the program reports).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import javaproperties

from automotive.bus.errors import ConfigError

_T = TypeVar("_T")
_REQUIRED: object = object()
_TRUE = {"true", "yes", "on", "1"}
_FALSE = {"false", "no", "off", "0"}


def _parse(text: str, source: str) -> dict[str, str]:
    """Key/value pairs of a properties text; a ConfigError names the file and line of a malformed entry."""
    values: dict[str, str] = {}
    line = 1
    try:
        for element in javaproperties.parse(text):
            if isinstance(element, javaproperties.KeyValue):
                if not element.key:
                    first = element.source.splitlines()[0].strip() if element.source else ""
                    raise ConfigError(f"{source}:{line}: a line has a value but no key: '{first}'")
                values[element.key] = element.value.rstrip()
            line += element.source.count("\n") + element.source.count("\r") - element.source.count("\r\n")
    except javaproperties.InvalidUEscapeError as error:
        raise ConfigError(f"{source}:{line}: invalid \\u escape '{error.escape}' (expected \\u and 4 hex digits)") \
            from None
    return values


@dataclass(frozen=True)
class PropertyKeys:
    """The property keys a program reads: exact keys, and families of keys (a prefix and any name after it, such as
    ``config.filter.<Topic>``)."""

    exact: frozenset[str] = frozenset()
    families: tuple[str, ...] = ()

    @classmethod
    def of(cls, *keys: str, roles: Iterable[str] = (), families: Iterable[str] = ()) -> PropertyKeys:
        """``keys``, plus for each endpoint role its topic and QoS profile (``topic.<Role>``, ``qos.<Role>.Profile``:
        automotive.bus.app.Application.writer/reader), plus the families' prefixes."""
        role_keys = {key for role in roles for key in (f"topic.{role}", f"qos.{role}.Profile")}
        return cls(frozenset(keys) | role_keys, tuple(families))

    def __or__(self, other: PropertyKeys) -> PropertyKeys:
        return PropertyKeys(self.exact | other.exact, tuple(dict.fromkeys((*self.families, *other.families))))

    def covers(self, key: str) -> bool:
        return key in self.exact or any(key.startswith(prefix) and len(key) > len(prefix) for prefix in self.families)

    def nearest(self, key: str) -> str | None:
        """The known key closest to ``key`` (a typo, another case), if any is close; a family's member keeps the
        name after the prefix (config.fliter.Circle: config.filter.Circle)."""
        candidates = set(self.exact)
        for prefix in self.families:
            if key.count(".") == prefix.count("."):  # shaped as the family's members: a misspelt prefix
                candidates.add(prefix + key.rpartition(".")[2])
        by_lower = {candidate.lower(): candidate for candidate in sorted(candidates)}
        import difflib  # only for a misspelt name: not part of every start

        close = difflib.get_close_matches(key.lower(), list(by_lower), n=1, cutoff=0.8)
        return by_lower[close[0]] if close else None


class Properties:
    """Key/value settings of one application, from a file and command-line overrides.

    Every getter records the key it was asked for; ``unused_keys()`` then lists what the file or the overrides
    hold that the application never read (a misspelt key, most likely). With a declaration (``declare``), an unknown
    key is refused up front, and ``undeclared_reads()`` lists the keys read that the declaration lacks.
    """

    def __init__(self, values: Mapping[str, str], source: str = "<properties>", folder: Path | None = None):
        self._values = dict(values)
        self._sources = {key: source for key in values}
        self.source = source
        self.folder = folder if folder is not None else Path.cwd()
        self._read: set[str] = set()
        self.declared: PropertyKeys | None = None
        self._undeclared_reads: list[str] = []

    @classmethod
    def parse(cls, text: str, source: str = "<properties>", folder: Path | None = None) -> Properties:
        return cls(_parse(text, source), source, folder)

    @classmethod
    def load(cls, path: str | Path) -> Properties:
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise ConfigError(f"{path}: properties file not found") from None
        except (OSError, UnicodeDecodeError) as error:
            raise ConfigError(f"{path}: cannot read properties file ({error})") from None
        return cls.parse(text, str(path), path.resolve().parent)

    def override(self, assignments: Iterable[str], source: str = "-D") -> None:
        """Apply ``key=value`` overrides (from ``-D`` on the command line)."""
        for assignment in assignments:
            key, separator, value = assignment.partition("=")
            key = key.strip()
            if not separator or not key:
                raise ConfigError(f"{source} {assignment!r}: expected key=value")
            self._values[key] = value.strip()
            self._sources[key] = source

    def declare(self, keys: PropertyKeys, program: str) -> None:
        """The keys ``program`` reads: a key set here (the file, the overrides) that it does not know is refused now,
        all of them in one line, each with where it was set and the nearest known key."""
        unknown = [key for key in self._values if not keys.covers(key)]
        if unknown:
            def described(key: str) -> str:
                nearest = keys.nearest(key)
                return f"'{key}' ({self.where(key)}{f'; did you mean {nearest!r}?' if nearest else ''})"
            raise ConfigError(f"{self.source}: unknown key(s) for {program}: {', '.join(map(described, unknown))}")
        self.declared = keys

    def undeclared_reads(self) -> list[str]:
        """The keys read that the declaration lacks (a defect of the program: a user cannot set them)."""
        return list(self._undeclared_reads)

    def __contains__(self, key: str) -> bool:
        return key in self._values

    def keys(self, prefix: str = "") -> list[str]:
        """The keys that start with ``prefix``, in the order they were set (not counted as read)."""
        return [key for key in self._values if key.startswith(prefix)]

    def unused_keys(self) -> list[str]:
        return [key for key in self._values if key not in self._read]

    def where(self, key: str) -> str:
        return self._sources.get(key, self.source)

    def _raw(self, key: str, default: object) -> str | None:
        self._read.add(key)
        if self.declared is not None and not self.declared.covers(key) and key not in self._undeclared_reads:
            self._undeclared_reads.append(key)
        if key in self._values:
            return self._values[key]
        if default is _REQUIRED:
            raise ConfigError(f"{self.source}: missing required key '{key}'")
        return None

    def _convert(self, key: str, raw: str, kind: str, convert: type[_T]) -> _T:
        try:
            return convert(raw)  # type: ignore[call-arg]
        except ValueError:
            raise ConfigError(f"{self.where(key)}: {key} = '{raw}' is not {kind}") from None

    def get_str(self, key: str, default: str | object = _REQUIRED) -> str:
        raw = self._raw(key, default)
        if raw is None:
            return default  # type: ignore[return-value]
        return raw

    def get_int(self, key: str, default: int | object = _REQUIRED, minimum: int | None = None,
                maximum: int | None = None) -> int:
        raw = self._raw(key, default)
        value = default if raw is None else self._convert(key, raw, "an integer", int)
        self._check_range(key, value, minimum, maximum)  # type: ignore[arg-type]
        return value  # type: ignore[return-value]

    def get_float(self, key: str, default: float | object = _REQUIRED, minimum: float | None = None,
                  maximum: float | None = None) -> float:
        raw = self._raw(key, default)
        value = default if raw is None else self._convert(key, raw, "a number", float)
        self._check_range(key, value, minimum, maximum)  # type: ignore[arg-type]
        return value  # type: ignore[return-value]

    def get_bool(self, key: str, default: bool | object = _REQUIRED) -> bool:
        raw = self._raw(key, default)
        if raw is None:
            return default  # type: ignore[return-value]
        if raw.lower() in _TRUE:
            return True
        if raw.lower() in _FALSE:
            return False
        raise ConfigError(f"{self.where(key)}: {key} = '{raw}' is not a boolean (expected true or false)")

    def get_choice(self, key: str, choices: Iterable[str], default: str | object = _REQUIRED) -> str:
        allowed = list(choices)
        value = self.get_str(key, default)
        if value not in allowed:
            raise ConfigError(f"{self.where(key)}: {key} = '{value}' is not one of {', '.join(allowed)}")
        return value

    def get_list(self, key: str, default: list[str] | object = _REQUIRED) -> list[str]:
        """A comma-separated list; empty items are dropped."""
        raw = self._raw(key, default)
        if raw is None:
            return list(default)  # type: ignore[call-overload, arg-type]
        return [item.strip() for item in raw.split(",") if item.strip()]

    def get_path(self, key: str, default: str | object = _REQUIRED) -> Path:
        """A file path; a relative one resolves against the folder of the properties file."""
        value = self.get_str(key, default)
        path = Path(value).expanduser()
        return path if path.is_absolute() else (self.folder / path)

    def _check_range(self, key: str, value: float | None, minimum: float | None, maximum: float | None) -> None:
        if value is None:
            return
        if (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
            low = "" if minimum is None else f"{minimum}"
            high = "" if maximum is None else f"{maximum}"
            raise ConfigError(f"{self.where(key)}: {key} = {value} is out of range (expected {low}..{high})")
