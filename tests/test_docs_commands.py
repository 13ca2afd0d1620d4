"""Every command the documentation shows is one the code accepts (issue 38: the docs said what the code did not).

Each command line of README.md and docs/ (in code blocks, and the inline ones that start with ``automotive``) is given
to the program's own command-line parser, in this process, through ``automotive``'s dispatcher as the user's shell
would: the parser's first successful parse ends the run there (nothing starts), a rejected option or value fails the
test with the parser's own line. Placeholders (``DIR``, ``FILE``, ``N``) get an example value.
"""

from __future__ import annotations

import argparse
import re
import shlex
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from automotive import command

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
COMMAND_START = re.compile(r"^(automotive(-(?!databus)[a-z-]+)?|scripts/launch)( |$)")  # not the package
# Example values for the placeholders the docs use in commands.
PLACEHOLDERS = {"DIR": "some-folder", "FILE": "drive.mcap", "N": "3", "APP": "vision", "NAME": "soak",
                "SAMPLES": "samples.jsonl", "COMMAND": "launch"}
pytestmark = pytest.mark.fast


def documented_commands() -> Iterator[tuple[str, str]]:
    """(where, command line) of every command in the docs."""
    for page in PAGES:
        text = page.read_text()
        blocks = re.findall(r"```[a-z]*\n(.*?)```", text, re.S)
        lines = [line.strip() for block in blocks for line in block.splitlines()]
        lines += re.findall(r"`([^`\n]+)`", re.sub(r"```.*?```", "", text, flags=re.S))
        for line in lines:
            line = re.split(r"\s+#\s", line)[0].strip()  # a comment after the command
            line = re.split(r"\s(?:&|\||;|&&)\s?", line)[0].strip()  # the first command of a pipe or a list
            if COMMAND_START.match(line) and "[" not in line and "..." not in line:
                yield f"{page.relative_to(ROOT)}", line


class Parsed(BaseException):
    """The program's parser accepted the command line (raised in place of running the program)."""


def arguments(line: str) -> list[str]:
    """The line as the ``automotive`` dispatcher's arguments."""
    words = [PLACEHOLDERS.get(word, word) for word in shlex.split(line)]
    if words[0] == "scripts/launch":
        return ["launch", *(word for word in words[1:] if word != "--no-setup")]
    if words[0].startswith("automotive-"):
        return ["run", words[0].removeprefix("automotive-"), *words[1:]]
    return words[1:]


COMMANDS = sorted(set(documented_commands()))


def test_the_docs_show_commands() -> None:
    assert len(COMMANDS) > 100  # a change in the docs' layout that this test no longer reads would pass empty


@pytest.mark.parametrize(("page", "line"), COMMANDS, ids=[line for _, line in COMMANDS])
def test_every_documented_command_is_accepted(page: str, line: str, monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    for name in ("parse_args", "parse_intermixed_args", "parse_known_args", "parse_known_intermixed_args"):
        original = getattr(argparse.ArgumentParser, name)

        def parsed(self: argparse.ArgumentParser, *args: Any, _original: Any = original, **kwargs: Any) -> Any:
            _original(self, *args, **kwargs)
            raise Parsed
        monkeypatch.setattr(argparse.ArgumentParser, name, parsed)
    args = arguments(line)
    if len(args) <= 2 and not any(word.startswith("-") for word in args):  # a command named in the text
        known = {**command.TOOLS, **command.GROUPS}
        assert not args or args[0] in known, f"{page}: `{line}`: no such command"
        if args and args[0] in command.GROUPS and len(args) == 2:
            assert args[1].replace("-", "_") in command.GROUPS[args[0]][0] or args[1] in command.GROUPS[args[0]][0], \
                f"{page}: `{line}`: no such {command.GROUPS[args[0]][1]}"
        if not (args and args[0] in command.TOOLS and len(args) == 2):  # `automotive launch stop` is parsed below
            return
    try:
        code: object = command.main(args)
    except Parsed:
        return
    except SystemExit as ended:
        code = ended.code
    errors = capsys.readouterr().err
    assert code in (0, None), f"{page}: `{line}` is refused: {errors.strip()}"


def test_the_guide_lists_every_benchmark() -> None:
    listed = next(line for line in (ROOT / "docs" / "README.md").read_text().splitlines()
                  if line.startswith("| `automotive bench NAME` |"))
    missing = [name for name in command.BENCHMARKS if name not in re.findall(r"[a-z-]+", listed)]
    assert not missing, f"docs/README.md's list of benchmarks lacks {missing}"
