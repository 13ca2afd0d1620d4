"""The core applications as separate processes: the collision-alert data flow, aggregation, deadlines, liveliness,
and an independent DDS tool (Cyclone's `cyclonedds` command line) looking at the system."""

from __future__ import annotations

import re
import signal
import subprocess
import threading
from pathlib import Path

import pytest
from dds_helpers import CYCLONEDDS_CLI

from automotive import config
from automotive.bus import stats
from automotive.types.Common import ClassificationEnum

HEADER = "Timestamp,timeStamp," + ",".join(
    f"object[{i}].{field}" for i in range(10) for field in
    ["id", "classification", "position[0]", "position[1]", "position[2]", "velocity[0]", "velocity[1]",
     "velocity[2]", "size[0]", "size[1]", "size[2]"]) + ",numObjects"
FAST = ["-D", "config.pubInterval=50"]


def vision_row(objects: list[tuple[int, list[float], list[float], list[float]]]) -> str:
    """One CSV row: objects as (classification, position, velocity, size); the rest zero."""
    cells = ["Sun Nov 22 08:00:00 2026", "1.7e+15"]
    for index in range(10):
        if index < len(objects):
            classification, position, velocity, size = objects[index]
            cells += [str(index), str(classification), *map(str, position), *map(str, velocity), *map(str, size)]
        else:
            cells += ["0"] * 11
    cells.append(str(len(objects)))
    return ",".join(cells)


TRUCK = ClassificationEnum.CLASSIFICATION_TRUCK.value  # 6: blinker 6 % 4 = 2, INDICATOR_RIGHT
CAR = ClassificationEnum.CLASSIFICATION_CAR.value  # 5: blinker 1, INDICATOR_LEFT


def scene(path: Path, rows: int = 40, tall_rows: range = range(10, 14)) -> Path:
    """A car ahead all along; a tall truck first in the list during ``tall_rows``."""
    lines = [HEADER]
    for row in range(rows):
        car = (CAR, [12.5, -1.5, 0.0], [3.25, 0.5, -0.25], [4.5, 1.5, 1.75])
        truck = (TRUCK, [20.0, 0.0, 0.0], [1.5, 0.0, 0.0], [10.0, 3.5, 2.5])
        lines.append(vision_row([truck, car] if row in tall_rows else [car]))
    path.write_text("\n".join(lines) + "\n")
    return path


def test_collision_alert_data_flow(apps, domain_id: int, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    domain = ["--domain", str(domain_id)]
    hmi = apps.start("hmi", "--ui", "console", *domain)
    platform = apps.start("vehicle_platform", *domain, *FAST)
    avoidance = apps.start("collision_avoidance", *domain)
    fusion = apps.start("sensor_fusion", *domain, *FAST)
    for process in (hmi, platform, avoidance, fusion):
        process.wait_for(r"matched a (reader|writer)")
    apps.start("vision", *domain, *FAST, "-D", f"dataFile={scene(tmp_path / 'scene.csv')}")

    hmi.wait_for(r"DRIVER ALERT: Driver attention required")
    hmi.wait_for(r"hmi debug: all clear")
    avoidance.wait_for(r"ALERT: driver attention needed")
    avoidance.wait_for(r"all clear: no object taller than 2.0 m")
    # commands follow the first object: the car (speed = velocity[0], steer = position[0], blinker = 5 % 4 = LEFT)
    platform.wait_for(r"command \d+ stamped \d+\.\d+: speed 3\.25, steer 12\.50, blinker INDICATOR_LEFT")
    # ... and the truck while it leads the list (6 % 4 = RIGHT)
    platform.wait_for(r"command \d+ stamped \d+\.\d+: speed 1\.50, steer 20\.00, blinker INDICATOR_RIGHT")
    # platform status flows back to collision avoidance
    line = avoidance.wait_for(r"command \d+: .*\(\d+ objects, [1-9]\d* status samples read\)")
    assert line
    # fusion copies every velocity component: checked on the fused list itself in test_sensor_fusion_copies_velocity
    assert "Traceback" not in hmi.output + platform.output + avoidance.output + fusion.output


def test_two_vision_sensors_are_aggregated(apps, domain_id: int, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    domain = ["--domain", str(domain_id)]
    fusion = apps.start("sensor_fusion", *domain, *FAST)
    data = scene(tmp_path / "scene.csv", tall_rows=range(0))
    for sensor in (1, 2):
        apps.start("vision", *domain, *FAST, "-D", f"dataFile={data}", "-D", f"config.sensorId={sensor}")
    fusion.wait_for(r"published list \d+: 2 object\(s\) from 2 vision sample\(s\) of sensor\(s\) 1,2")


def test_sensor_fusion_copies_velocity_and_event_mode(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                      tmp_path: Path) -> None:
    from dds_helpers import make_bus, take_samples

    from automotive.types.Sensor import SensorObjectList

    bus = make_bus(domain_id)
    reader = bus.reader("SensorObjects", SensorObjectList, "SensorFusion")
    domain = ["--domain", str(domain_id)]
    fusion = apps.start("sensor_fusion", *domain, "-D", "config.mode=event")
    apps.start("vision", *domain, *FAST, "-D", f"dataFile={scene(tmp_path / 'scene.csv', tall_rows=range(0))}")
    # the 15 s of take_samples start once fusion publishes, not while the two programs may still be importing on a
    # busy machine (a clean clone's --busy run took none in 15 s from the start)
    fusion.wait_for(r"published list \d+")
    lists = take_samples(reader, 3)
    assert len(lists) >= 3
    car = lists[-1].objects[0]
    assert (list(car.position), list(car.velocity), list(car.size)) == \
        ([12.5, -1.5, 0.0], [3.25, 0.5, -0.25], [4.5, 1.5, 1.75])
    assert ClassificationEnum(car.classification) == ClassificationEnum.CLASSIFICATION_CAR
    bus.close()


SHORT_QOS = [
    # Vision/fusion deadlines of 10 s / 11 s and the alert liveliness of 60 s, shortened so a test sees them expire.
    (r"<deadline><period><sec>10</sec><nanosec>0</nanosec></period></deadline>",
     "<deadline><period><sec>0</sec><nanosec>500000000</nanosec></period></deadline>"),
    (r"<deadline><period><sec>11</sec><nanosec>0</nanosec></period></deadline>",
     "<deadline><period><sec>1</sec><nanosec>0</nanosec></period></deadline>"),
    (r"<lease_duration><sec>60</sec><nanosec>0</nanosec></lease_duration>",
     "<lease_duration><sec>1</sec><nanosec>0</nanosec></lease_duration>"),
]


@pytest.fixture
def short_qos(tmp_path: Path) -> Path:
    text = config.qos_file().read_text()
    for pattern, replacement in SHORT_QOS:
        text, count = re.subn(pattern, replacement, text)
        assert count > 0, pattern
    path = tmp_path / "short_qos.xml"
    path.write_text(text)
    return path


def test_stopped_vision_makes_fusion_report_a_deadline_miss(apps, domain_id: int, tmp_path: Path,  # type: ignore[no-untyped-def]
                                                            short_qos: Path) -> None:
    common = ["--domain", str(domain_id), "-D", f"qos.File={short_qos}", *FAST]
    fusion = apps.start("sensor_fusion", *common)
    vision = apps.start("vision", *common, "-D", f"dataFile={scene(tmp_path / 'scene.csv')}")
    fusion.wait_for(r"published list")
    assert fusion.count("requested deadline missed") == 0
    # A hung sensor: its writer still exists but sends nothing. (A sensor that exits cleanly unregisters its
    # instance, and DDS checks deadlines only on live instances.)
    with vision.frozen():
        fusion.wait_for(r"\[VisionTopic\] requested deadline missed", timeout=15)


def test_killed_collision_avoidance_loses_liveliness_and_recovers(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                                  short_qos: Path, tmp_path: Path) -> None:
    common = ["--domain", str(domain_id), "-D", f"qos.File={short_qos}"]
    records = tmp_path / "hmi.jsonl"
    hmi = apps.start("hmi", "--ui", "console", *common, "--stats", str(records))
    avoidance = apps.start("collision_avoidance", *common)
    hmi.wait_for(r"\[AlertTopic\] reader matched a writer")
    avoidance.stop(signal.SIGKILL)
    hmi.wait_for(r"alert source LOST", timeout=20)
    apps.start("collision_avoidance", *common)
    hmi.wait_for(r"alert source back: the alert writer's liveliness was regained", timeout=20)
    # what the driver was told, as status records (automotive bench soak counts the losses)
    assert [record["alive"] for record in stats.read(records, "source")] == [False, True]


def test_cyclonedds_tool_lists_our_topics_and_decodes_alerts(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                              tmp_path: Path) -> None:
    domain = ["--domain", str(domain_id)]
    avoidance = apps.start("collision_avoidance", *domain)
    fusion = apps.start("sensor_fusion", *domain, *FAST)
    # a tall object in every row: collision avoidance keeps writing the alert
    apps.start("vision", *domain, *FAST, "-D", f"dataFile={scene(tmp_path / 'scene.csv', tall_rows=range(40))}")
    avoidance.wait_for(r"ALERT: driver attention needed")
    fusion.wait_for(r"published list")

    listing = subprocess.run([CYCLONEDDS_CLI, "ls", "-i", str(domain_id), "-r", "3s", "--suppress-progress-bar",
                              "--color", "none"], capture_output=True, text=True, timeout=60).stdout
    for topic, type_name in [("AlertTopic", "Alerts::DriverAlerts"), ("VisionTopic", "Vision::VisionSensor"),
                             ("SensorObjects", "Sensor::SensorObjectList"),
                             ("PlatformControl", "Platform::PlatformControl")]:
        assert re.search(rf"{topic}.*\n.*\n.*Typename\s*│\s*{re.escape(type_name)}", listing), (topic, listing)
    assert "Participant collision_avoidance" in listing

    # `cyclonedds subscribe` prints samples until stopped: read until a decoded alert shows up, then stop it.
    subscriber = subprocess.Popen([CYCLONEDDS_CLI, "subscribe", "AlertTopic", "-i", str(domain_id), "-r", "3s",
                                   "--suppress-progress-bar", "--color", "none", "--qos", "scan-random"],
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    timer = threading.Timer(60, subscriber.kill)  # bound the wait even if the tool never prints
    timer.start()
    decoded = ""
    try:
        assert subscriber.stdout is not None
        for line in subscriber.stdout:
            decoded += line
            if re.search(r"DriverAlerts\(\s*blindSpotDriver=False,.*?driverAttention=True", decoded, re.S):
                break
    finally:
        timer.cancel()
        subscriber.kill()
        subscriber.wait()
    assert re.search(r"DriverAlerts\(\s*blindSpotDriver=False,.*?driverAttention=True", decoded, re.S), decoded
