"""A reader of Java-style ``.properties`` files with typed getters.

Syntax (as java.util.Properties): ``key=value``, ``key: value`` or ``key value``; ``#`` and ``!`` start comment lines;
blank lines are ignored; keys and values are trimmed; a line ending in a backslash continues on the next line; ``\\=``,
``\\:``, ``\\ ``, ``\\t``, ``\\n`` and ``\\\\`` are escapes.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TypeVar

from automotive.errors import ConfigError

_T = TypeVar("_T")
_REQUIRED: object = object()
_ESCAPES = {"t": "\t", "n": "\n", "r": "\r", "f": "\f"}
_TRUE = {"true", "yes", "on", "1"}
_FALSE = {"false", "no", "off", "0"}


def _unescape(text: str) -> str:
    return re.sub(r"\\(.)", lambda m: _ESCAPES.get(m.group(1), m.group(1)), text)


def _split_key_value(line: str) -> tuple[str, str]:
    """Split at the first unescaped '=', ':' or whitespace, as Java does."""
    index = 0
    while index < len(line):
        char = line[index]
        if char == "\\":
            index += 2
            continue
        if char in "=:" or char.isspace():
            break
        index += 1
    key, rest = line[:index], line[index:].lstrip()
    if rest[:1] in ("=", ":"):
        rest = rest[1:].lstrip()
    return _unescape(key), _unescape(rest.rstrip())


def _logical_lines(text: str) -> Iterable[tuple[int, str]]:
    """Yield (first line number, joined line) with continuation lines joined and comments dropped."""
    pending: list[str] = []
    start = 0
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip() if not pending else raw.lstrip()
        if not pending:
            if not line or line[0] in "#!":
                continue
            start = number
        trailing = len(line) - len(line.rstrip("\\"))
        if trailing % 2 == 1:  # an odd number of backslashes: the last one continues the line
            pending.append(line[:-1])
            continue
        pending.append(line)
        yield start, "".join(pending)
        pending = []
    if pending:
        yield start, "".join(pending)


class Properties:
    """Key/value settings of one application, from a file and command-line overrides.

    Every getter records the key it was asked for; ``unused_keys()`` then lists what the file or the overrides
    hold that the application never read (a misspelt key, most likely).
    """

    def __init__(self, values: Mapping[str, str], source: str = "<properties>", folder: Path | None = None):
        self._values = dict(values)
        self._sources = {key: source for key in values}
        self.source = source
        self.folder = folder if folder is not None else Path.cwd()
        self._read: set[str] = set()

    @classmethod
    def parse(cls, text: str, source: str = "<properties>", folder: Path | None = None) -> Properties:
        values: dict[str, str] = {}
        for number, line in _logical_lines(text):
            key, value = _split_key_value(line)
            if not key:
                raise ConfigError(f"{source}:{number}: a line has a value but no key: '{line}'")
            values[key] = value
        return cls(values, source, folder)

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

    def __contains__(self, key: str) -> bool:
        return key in self._values

    def unused_keys(self) -> list[str]:
        return [key for key in self._values if key not in self._read]

    def where(self, key: str) -> str:
        return self._sources.get(key, self.source)

    def _raw(self, key: str, default: object) -> str | None:
        self._read.add(key)
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
            return list(default)  # type: ignore[call-overload]
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
