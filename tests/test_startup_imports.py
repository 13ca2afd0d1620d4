"""What a program imports to start: numpy and importlib.metadata only where they are used.

An application's start-up is mostly its imports (docs/measurements/suite-time.md): numpy's is about a sixth of it,
importlib.metadata's (and the search of every path entry it makes) 10-25 ms. The programs that decode no numpy view
and make no numpy array (the HMI, the vehicle platform, the vision sensor, the shape application) import neither; a
program that views a sequence as an array (collision avoidance, sensor fusion) imports numpy when it first does.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

WITHOUT_NUMPY = ["automotive.apps.hmi", "automotive.apps.vehicle_platform", "automotive.apps.vision",
                 "automotive.apps.collision_avoidance", "automotive.tools.shapes.shape_main",
                 "automotive.tools.launch.launch"]
LOADED = "import sys, json; print(json.dumps(sorted(m for m in ('numpy', 'importlib.metadata') if m in sys.modules)))"


def loaded_after(code: str) -> list[str]:
    result = subprocess.run([sys.executable, "-c", f"{code}\n{LOADED}"], capture_output=True, text=True, timeout=60,
                            env={**os.environ, "AUTOMOTIVE_LOG_LEVEL": "error"})
    assert result.returncode == 0, result.stderr
    loaded: list[str] = json.loads(result.stdout.splitlines()[-1])
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
