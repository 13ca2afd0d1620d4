"""What a program imports to start: numpy and importlib.metadata only where they are used.

An application's start-up is mostly its imports (docs/measurements/suite-time.md): numpy's is about a sixth of it,
importlib.metadata's (and the search of every path entry it makes) 10-25 ms. The programs that decode no numpy view
and make no numpy array (the HMI, the vehicle platform, the vision sensor, the shape application) import neither; a
program that views a sequence as an array (collision avoidance, sensor fusion) imports numpy when it first does.
Also what a program's import leaves for later: the standard modules a dependency loads but does not use yet
(automotive.start.DEFERRED), and the dataclasses' methods, compiled once per machine (automotive.methodcache).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from automotive.methodcache import FILENAME

WITHOUT_NUMPY = ["automotive.apps.hmi", "automotive.apps.vehicle_platform", "automotive.apps.vision",
                 "automotive.apps.collision_avoidance", "automotive.tools.shapes.shape_main",
                 "automotive.tools.launch.launch"]
LAZY = ("numpy", "importlib.metadata")  # imported where they are used, not at start


def run_code(code: str, **environment: str) -> str:
    """What a fresh interpreter running ``code`` (with ``environment`` added to this one's) prints."""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                            env={**os.environ, "AUTOMOTIVE_LOG_LEVEL": "error", **environment})
    assert result.returncode == 0, result.stderr
    return result.stdout


def loaded_after(code: str, modules: tuple[str, ...] = LAZY) -> list[str]:
    """Which of ``modules`` a fresh interpreter has loaded once it ran ``code``."""
    listing = f"import sys, json; print(json.dumps(sorted(m for m in {modules!r} if m in sys.modules)))"
    loaded: list[str] = json.loads(run_code(f"{code}\n{listing}").splitlines()[-1])
    return loaded


@pytest.mark.parametrize("module", WITHOUT_NUMPY)
def test_a_program_that_needs_no_numpy_imports_neither_it_nor_importlib_metadata(module: str) -> None:
    # The fast paths' version gate runs as every program starts (cyclone.start()).
    assert loaded_after(f"import {module}\nfrom automotive import cyclone\nassert cyclone.start()") == []


def test_the_shape_application_publishes_and_subscribes_without_numpy(domain_id: int) -> None:
    for role in ("-P", "-S"):
        code = ("from automotive.tools.shapes.shape_main import main\n"
                f"assert main(['{role}', '-t', 'Square', '-d', '{domain_id}', '--num-iterations', '2']) == 0")
        assert loaded_after(code) == [], role


def test_a_view_of_a_sequence_brings_numpy_in_when_it_is_made() -> None:
    code = """
from automotive.cyclone.codecs import codec_for, numpy_if_loaded
from automotive.types.Common import ClassificationEnum, POSIXTimestamp
from automotive.types.Sensor import RangeModeEnum, SensorObject, SensorObjectList
codec = codec_for(SensorObjectList)
obj = SensorObject(classification=ClassificationEnum.CLASSIFICATION_CAR, position=[1.0, 2.0, 3.0],
                   velocity=[0.0] * 3, size=[4.0, 1.5, 1.75], amplitude=1.0, rangeMode=RangeModeEnum.RANGE_SHORT,
                   rangeRate=0.0)
sample = SensorObjectList(timestamp=POSIXTimestamp(s=1, ns=2), objects=[obj, obj])
data = codec.encode(sample)
assert numpy_if_loaded() is None and codec.decode(data) == sample
viewed = codec.decode(data, views=True)
assert numpy_if_loaded() is not None and viewed.objects["size"][1, 2] == 1.75
assert codec.encode(viewed) == data and codec.with_dataclasses(viewed) == sample
"""
    assert loaded_after(code) == ["numpy"]


# -- modules a dependency imports but uses only later (automotive.start.DEFERRED) ------------------------------------

APPLICATIONS = ["automotive.apps.vision", "automotive.apps.lidar", "automotive.apps.sensor_fusion",
                "automotive.apps.collision_avoidance", "automotive.apps.vehicle_platform", "automotive.apps.hmi",
                "automotive.apps.camera_pub", "automotive.apps.camera_sub"]
# What the deferred modules would bring in with them.
NOT_LOADED = ("asyncio", "ssl", "urllib.request", "http.client", "email")


@pytest.mark.parametrize("module", APPLICATIONS)
def test_an_application_started_loads_none_of_the_deferred_modules(module: str) -> None:
    # Fails when a new version of a dependency uses a deferred module as it loads: then take it out of DEFERRED.
    assert loaded_after(f"from automotive.start import import_program\nimport_program({module!r})", NOT_LOADED) == []


def test_the_dependencies_use_the_real_modules_through_their_stand_ins(domain_id: int, tmp_path: Path) -> None:
    page = tmp_path / "page.txt"
    page.write_text("read through urllib.request\n")
    code = f"""
import types
from automotive.start import import_program
import_program("automotive.apps.vision")
import cyclonedds.core, xml.sax.saxutils
from cyclonedds.core import GuardCondition, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.util import duration

# Cyclone's async wait (WaitSet.wait_async), through cyclonedds.core's stand-in of asyncio.
participant = DomainParticipant({domain_id})
waitset, guard = WaitSet(participant), GuardCondition(participant)
waitset.attach(guard)
guard.set(True)
loop = cyclonedds.core.asyncio.new_event_loop()
assert loop.run_until_complete(waitset.wait_async(duration(seconds=10))) == 1
loop.close()

# xml.sax.saxutils's URL input, through its stand-in of urllib.request.
source = xml.sax.saxutils.prepare_input_source({page.as_uri()!r})
text = source.getByteStream().read().decode().strip()

# Everyone importing them now gets the real modules.
import asyncio, urllib.request
assert type(asyncio) is types.ModuleType and type(urllib.request) is types.ModuleType, (asyncio, urllib.request)
assert cyclonedds.core.asyncio.get_event_loop_policy() is asyncio.get_event_loop_policy()
print(text)
"""
    assert run_code(code).splitlines()[-1] == "read through urllib.request"


# -- the dataclasses' methods, compiled once (automotive.methodcache) ------------------------------------------------

def test_a_program_started_again_compiles_none_of_its_dataclass_methods(tmp_path: Path) -> None:
    code = """
from automotive.start import import_program
import_program("automotive.apps.sensor_fusion")
import dataclasses
assert "exec" not in vars(dataclasses)  # only while the program imported
"""
    cache = tmp_path / "automotive" / FILENAME
    run_code(code, XDG_CACHE_HOME=str(tmp_path))
    written = cache.stat()
    assert written.st_size > 100_000  # Cyclone's XTypes and QoS classes, the generated types, the package's own
    run_code(code, XDG_CACHE_HOME=str(tmp_path))
    again = cache.stat()
    # Written only when a process compiled something new: the second start found every method in it.
    assert (again.st_ino, again.st_mtime_ns) == (written.st_ino, written.st_mtime_ns)
