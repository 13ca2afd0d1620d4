"""Bad input to the applications: one clear line naming the file, key or value; non-zero exit; no traceback."""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from apprunner import command_of
from test_system import HEADER, scene

from automotive import command, config
from automotive.bus.cli import domain_id

ROOT = Path(__file__).resolve().parent.parent


def assert_one_line_error(result, pattern: str) -> None:  # type: ignore[no-untyped-def]
    assert result.returncode == 2, result.stdout + result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert re.search(pattern, lines[0]), lines[0]
    assert "Traceback" not in result.stdout + result.stderr


def test_malformed_rows_are_reported_once_and_skipped(apps, domain_id: int, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    good = scene(tmp_path / "good.csv", rows=3).read_text().splitlines()
    bad_rows = [
        good[1].replace(",12.5,", ",twelve,", 1),  # not a number
        ",".join(good[1].split(",")[:50]),  # too few columns
        good[1].rsplit(",", 1)[0] + ",11",  # numObjects outside 0..10
    ]
    data = tmp_path / "vision.csv"
    data.write_text("\n".join([HEADER, good[1], *bad_rows, good[2]]) + "\n")
    result = apps.run("vision", "--domain", str(domain_id), "--count", "6", "-D", "config.pubInterval=10",
                      "-D", f"dataFile={data}")
    assert result.returncode == 0, result.stderr
    for line_number in (3, 4, 5):
        assert result.stdout.count(f"vision.csv:{line_number}:") == 1, result.stdout  # once, though rows wrap
    assert "numObjects 11 is outside 0..10" in result.stdout
    assert result.stdout.count("published sample") == 6


@pytest.mark.parametrize("app", ["vision", "vehicle_platform"])
def test_data_file_without_usable_rows(apps, app: str, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    data = tmp_path / "empty.csv"
    data.write_text("just,a,header\n1,2\n")
    assert_one_line_error(apps.run(app, "-D", f"dataFile={data}"),
                          rf"^{command_of(app)}: .*empty.csv: no usable data row")


def test_unreadable_data_file(apps, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    assert_one_line_error(apps.run("vision", "-D", f"dataFile={tmp_path}/missing.csv"),
                          r"^automotive-vision: .*missing.csv: cannot read the data file")


def test_missing_required_property(apps, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    text = config.properties_file("vision").read_text()
    props = tmp_path / "vision.properties"
    text = text.replace("qos.File=../qos/", f"qos.File={config.shipped_dir()}/qos/")
    props.write_text("\n".join(line for line in text.splitlines() if not line.startswith("dataFile")))
    assert_one_line_error(apps.run("vision", "--properties", str(props)),
                          r"^automotive-vision: .*vision.properties: missing required key 'dataFile'$")


@pytest.mark.parametrize("app,args,pattern", [
    ("sensor_fusion", ["-D", "qos.Vision.Profile=Nonexistent"], r"no QoS profile 'AutomotiveLibrary::Nonexistent'"),
    ("sensor_fusion", ["-D", "config.mode=sometimes"], r"config.mode = 'sometimes' is not one of periodic, event"),
    ("vision", ["-D", "config.pubInterval=0"], r"config.pubInterval = 0 is out of range"),
    ("vision", ["-D", "config.sensorId=-4"], r"config.sensorId = -4 is out of range"),
    ("collision_avoidance", ["-D", "config.alertSize=tall"], r"config.alertSize = 'tall' is not a number"),
    ("hmi", ["-D", "config.mallocTrim=-5"], r"config.mallocTrim = -5(\.0)? is out of range"),
])
def test_bad_properties(apps, app: str, args: list[str], pattern: str) -> None:  # type: ignore[no-untyped-def]
    assert_one_line_error(apps.run(app, *args), rf"^{command_of(app)}: .*{pattern}")


@pytest.mark.parametrize(("path", "pattern"), [("", "the path is empty: give a file"),
                                               (".", r"\.: is a folder, not a file")])
def test_an_empty_or_folder_properties_path_is_named_as_given(apps, path: str,  # type: ignore[no-untyped-def]
                                                               pattern: str) -> None:
    assert_one_line_error(apps.run("vision", "--properties", path),
                          rf"^automotive-vision: argument --properties: {pattern} ")



@pytest.mark.parametrize("app,args,pattern", [
    ("hmi", ["-D", "topic.Alerts=no spaces allowed"],
     r"topic 'no spaces allowed': Cyclone refused it \(\[DDS_RETCODE_BAD_PARAMETER\]"),
    ("shape_main", ["-S", "-t", "no spaces"], r"topic 'no spaces': Cyclone refused it \(\[DDS_RETCODE_BAD_PARAMETER\]"),
    ("shape_main", ["-S", "-t", "Square", "-f", "10", "--time-filter", "100"],  # a deadline under the time filter
     r"the reader of Square with these QoS options: Cyclone refused it \(\[DDS_RETCODE_INCONSISTENT_POLICY\]"),
])
def test_entities_cyclone_refuses_end_with_one_line(apps, domain_id: int, app: str, args: list[str],  # type: ignore[no-untyped-def]
                                                    pattern: str) -> None:
    domain = ["-d", str(domain_id)] if app == "shape_main" else ["--domain", str(domain_id)]
    prog = "automotive shape-main" if app == "shape_main" else f"automotive-{app}"
    assert_one_line_error(apps.run(app, *domain, *args), rf"^{prog}: {pattern}")

# The commands the README and docs/ print, started as printed: scripts/launch through its shebang with whatever the
# PATH has (not the project's .venv: it installs what is needed and runs the launcher of .venv), and the console
# script `automotive` of .venv/bin with its subcommands (the launcher's, the benchmarks').
COMMANDS = [["launch"], ["shape-main"]] + [["bench", name] for name in command.BENCHMARKS]
PRINTED_COMMANDS = [(["scripts/launch"], "scripts/launch")] + [
    ([".venv/bin/automotive", *words], f"automotive {' '.join(words)}") for words in COMMANDS]


@pytest.mark.parametrize(("words", "prog"), PRINTED_COMMANDS, ids=lambda value: str(value))
def test_commands_run_as_printed_and_refuse_bad_arguments_in_one_line(words: list[str], prog: str) -> None:
    env = {key: value for key, value in os.environ.items() if key not in ("VIRTUAL_ENV", "PYTHONPATH")}
    env["PATH"] = os.pathsep.join(part for part in env.get("PATH", "").split(os.pathsep)
                                  if Path(part).resolve() != (ROOT / ".venv" / "bin").resolve())
    usage = subprocess.run([*words, "--help"], cwd=ROOT, capture_output=True, text=True, env=env, timeout=120)
    assert usage.returncode == 0 and f"usage: {prog}" in usage.stdout, usage.stdout + usage.stderr
    result = subprocess.run([*words, "--no-such-option"], cwd=ROOT, capture_output=True, text=True, env=env,
                            timeout=120)
    assert_one_line_error(result, rf"^{prog}: unrecognized arguments: --no-such-option")


def every_command() -> list[list[str]]:
    """Each program as a user starts it: ``automotive`` with its subcommand, or an application's own script."""
    return ([[name] for name in command.TOOLS] + [["bench", name] for name in command.BENCHMARKS]
            + [[f"automotive-{name.replace('_', '-')}"] for name in command.APPS])


def started(words: list[str]) -> list[str]:
    script = words[0] if words[0].startswith("automotive-") else "automotive"
    return [str(Path(sys.executable).parent / script), *(words[1:] if script != "automotive" else words)]


# Programs that join no domain of their own choosing (shape_main: the suite's -d; bench fastpath: its own namespace).
WITHOUT_DOMAIN_OPTION = (["bench", "fastpath"], ["config"], ["shape-main"], ["zenoh-certs"])


def test_the_programs_without_a_domain_option_are_the_listed_ones() -> None:
    for words in WITHOUT_DOMAIN_OPTION:
        usage = subprocess.run([*started(words), "--help"], capture_output=True, text=True, timeout=120)
        assert usage.returncode == 0 and "--domain" not in usage.stdout, f"{words}: {usage.stdout}{usage.stderr}"


@pytest.mark.parametrize("words", [words for words in every_command() if words not in WITHOUT_DOMAIN_OPTION],
                         ids=" ".join)
def test_every_program_with_a_domain_option_refuses_an_impossible_domain_in_one_line(words: list[str]) -> None:
    # A domain above 231 has no RTPS ports for every participant index: said on the command line, not as Cyclone's
    # failures to send at start-up (automotive.bus.ports).
    result = subprocess.run([*started(words), "--domain", "232"], capture_output=True, text=True, timeout=120)
    assert_one_line_error(result, r": argument --domain: expected a domain id 0..231, not '232'")


@pytest.mark.parametrize("text", ["-1", "232", "999", "x", ""])
def test_domain_id_type_refuses(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=rf"^expected a domain id 0..231, not '{text}'$"):
        domain_id(text)
    assert domain_id("0") == 0 and domain_id("231") == 231
