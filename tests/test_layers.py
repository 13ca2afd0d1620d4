"""The layer rules import-linter cannot express: only automotive.cyclone touches Cyclone DDS Python's private
internals (modules whose name starts with an underscore, cyclonedds.internal, and the private attributes the fast
paths use), every program is a module with main(argv), and the rules of the code that tests share: Cyclone's racy
get_matched_* asked through automotive.cyclone.matched, no domain id of the tests' pool named by a test."""

from __future__ import annotations

import ast
import importlib
import importlib.metadata
import subprocess
import sys
from pathlib import Path

import pytest
from domain_ids import CLAIM_WAIT_S, LEAST_CLAIMED, MOST_CLAIMED, TEST_DOMAIN_IDS, foreign_domain_ids

import automotive
from automotive import command, start

PACKAGE = Path(automotive.__file__).resolve().parent
CYCLONE = PACKAGE / "cyclone"
GENERATED = PACKAGE / "types"
# Private attributes of Cyclone's entities and buffers that the fast paths use (cyclone/serdata.py, fastpath.py).
PRIVATE_ATTRIBUTES = {"_ref", "_use_version_2", "_bytes", "_clayer"}


def private_module(name: str) -> bool:
    parts = name.split(".")
    return parts[0] == "cyclonedds" and (name.startswith("cyclonedds.internal")
                                         or any(part.startswith("_") and part != "__idlc__" for part in parts[1:]))


def offences(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [f"line {node.lineno}: import {alias.name}" for alias in node.names if private_module(alias.name)]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names = [f"{node.module}.{alias.name}" for alias in node.names]
            if private_module(node.module) or any(private_module(name) for name in names):
                found.append(f"line {node.lineno}: from {node.module} import {', '.join(a.name for a in node.names)}")
        elif isinstance(node, ast.Attribute) and node.attr in PRIVATE_ATTRIBUTES:
            found.append(f"line {node.lineno}: .{node.attr}")
    return found


SOURCES = sorted(path for path in PACKAGE.rglob("*.py")
                 if CYCLONE not in path.parents and GENERATED not in path.parents)


def test_the_rule_sees_private_imports() -> None:
    assert private_module("cyclonedds._clayer") and private_module("cyclonedds.idl._builder")
    assert private_module("cyclonedds.internal") and not private_module("cyclonedds.idl.types")
    assert len(SOURCES) > 40


@pytest.mark.parametrize("path", SOURCES, ids=lambda path: str(path.relative_to(PACKAGE)))
def test_only_the_cyclone_layer_touches_cyclone_internals(path: Path) -> None:
    assert offences(path) == [], f"{path.relative_to(PACKAGE)} uses Cyclone internals outside automotive.cyclone"


# The modules that are no program: the tools' shared modules and their rooms' parts, the benchmarks' helpers.
NOT_PROGRAMS = {"__init__", "children", "flows", "cloudview", "wsrelay", "netlab", "ddsperf", "mcap_recover",
                "plan", "display", "supervisor", "registry", "logfile",  # automotive.tools.launch's parts
                "discovery", "model", "probes", "rules", "server", "text"}  # automotive.tools.monitor's parts
PROGRAMS = sorted(".".join(["automotive", *path.relative_to(PACKAGE).with_suffix("").parts])
                  for folder in ("apps", "tools", "bench")
                  for path in (PACKAGE / folder).glob("**/*.py" if folder == "tools" else "*.py")
                  if path.stem not in NOT_PROGRAMS)


SCRIPTS = {entry.name: entry.value for entry in importlib.metadata.distribution("automotive-databus").entry_points
           if entry.group == "console_scripts"}
# Helpers that are programs for maintainers only (python -m ...), on no user's PATH.
INTERNAL = {"automotive.tools.support.make_scene_data", "automotive.tools.support.delay_relay",
            "automotive.bench.rti_reader", "automotive.bench.dds_readers"}


@pytest.mark.parametrize("module", PROGRAMS)
def test_every_program_has_main_with_argv_and_a_command(module: str) -> None:
    main = importlib.import_module(module).main
    assert "argv" in main.__code__.co_varnames[:main.__code__.co_argcount], module
    commands = {entry.module for table in (command.TOOLS, command.APPS, command.BENCHMARKS) for entry in table.values()}
    if module in INTERNAL:
        assert module not in commands and f"{module}:main" not in SCRIPTS.values()
    else:
        assert module in commands, f"{module} is no subcommand of automotive (automotive/command.py)"
    if module.startswith("automotive.apps."):
        started = {getattr(start, value.split(":")[1]).module for value in SCRIPTS.values()}
        assert module in started, f"{module} has no console script in pyproject.toml (automotive.start)"


TESTS = Path(__file__).resolve().parent
TEST_SOURCES = sorted(path for path in TESTS.rglob("*.py") if "node_modules" not in path.parts)
RACY_CALLS = ("get_matched_subscriptions", "get_matched_publications")


def racy_calls(path: Path) -> list[str]:
    """Lines of ``path`` that call Cyclone's get_matched_* directly (ast: docstrings and comments do not count)."""
    tree = ast.parse(path.read_text(), str(path))
    return [f"{path}:{node.lineno}" for node in ast.walk(tree)
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in RACY_CALLS]


def test_the_matched_endpoints_are_asked_only_through_automotive_cyclone_matched() -> None:
    """Cyclone DDS Python's get_matched_* raise IndexError when an endpoint matches between its two C calls: every
    caller, programs and tests, asks through automotive.cyclone.matched, which asks again. The race's own test calls
    them directly on purpose."""
    allowed = {CYCLONE / "matched.py", TESTS / "test_runtime.py"}
    found = [line for path in [*sorted(PACKAGE.rglob("*.py")), *TEST_SOURCES] if path not in allowed
             for line in racy_calls(path)]
    assert not found, "call automotive.cyclone.matched.matched_subscriptions/_publications instead: " + ", ".join(found)


def test_the_racy_call_rule_sees_a_direct_call(tmp_path: Path) -> None:
    source = tmp_path / "peer.py"
    source.write_text('"""get_matched_subscriptions() in a docstring"""\nwriter.get_matched_subscriptions()\n')
    assert racy_calls(source) == [f"{source}:2"]


def test_no_test_names_a_domain_id_that_conftest_hands_out() -> None:
    """A test's own domain comes from the domain_id fixtures; the few it may name are domain_ids.NAMED_DOMAIN_IDS."""
    found = [line for path in TEST_SOURCES for line in foreign_domain_ids(path)]
    assert not found, "take the domain_id or other_domain_id fixture instead: " + ", ".join(found)


@pytest.mark.not_fast
def test_another_run_on_the_host_never_claims_a_domain_id_this_one_holds(domain_id: int) -> None:
    """A second test run (here a process of its own, as another clone's worker is) asked for this worker's domain id
    first gets others: two runs on one domain would hear each other's samples."""
    code = ("import sys; sys.path.insert(0, sys.argv[1]); from domain_ids import claim_domain_ids; "
            "print(*claim_domain_ids([int(sys.argv[2])]))")
    result = subprocess.run([sys.executable, "-c", code, str(TESTS), str(domain_id)], capture_output=True, text=True,
                            timeout=CLAIM_WAIT_S + 60)
    assert result.returncode == 0, result.stderr
    claimed = [int(domain) for domain in result.stdout.split()]
    assert domain_id not in claimed and LEAST_CLAIMED <= len(claimed) <= MOST_CLAIMED, claimed
    assert set(claimed) <= set(TEST_DOMAIN_IDS), claimed


def test_the_domain_rule_sees_a_named_domain(tmp_path: Path) -> None:
    source = tmp_path / "test_peer.py"
    pooled, named, outside = 58, 7, 232  # (spelt apart, so that the rule does not see this test's own text)
    source.write_text(f'REPLAY_DOMAIN = {pooled}\napps.start("vision", "--domain", "{named}")\n'
                      f'bus = make_bus({pooled - 18})\napps.run("vision", "--domain", "{outside}")\n')
    assert foreign_domain_ids(source) == [f"{source}:1: domain 58", f"{source}:3: domain 40"]
