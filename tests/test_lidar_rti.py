"""The LiDAR and the shapes tool with a real RTI Connext peer (RTI Connector, tests/rti_peer.py), on loopback.

- An RTI writer of ShapeTypeExtended registered as "ShapeType" on Circle, as RTI Shapes Demo publishes: our LiDAR
  draws its sphere, and removes it when the RTI writer disposes the instance or goes away.
- Our shapes publisher reaches an RTI reader with a Shapes Demo subscriber's default QoS (best effort, XCDR1).
- An RTI reader of PointCloud2_ declared as the original IDL declares it (data_ bounded to 368,640 bytes) receives
  our LiDAR's clouds intact: header, fields and every data byte, compared with a local render of the same scene.
"""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("rticonnextdds_connector")

from dds_helpers import wait_until, write_until
from lidar_helpers import Clouds, circle, points_of, with_colour
from rti_peer import RTI_XML, RtiPeer

from automotive.bus.endpoints import Databus
from automotive.cyclone.matched import matched_subscriptions
from automotive.sim.scene import SHAPE_RGB, LidarScene, ScanGrid
from automotive.types.automotive import ShapeType
from automotive.types.sensor_msgs.msg.dds_ import PointCloud2_
from automotive.wire.pointcloud import FLOAT32, decode_point_cloud2

# Profiles of this file's RTI endpoints, added to a copy of the peer's XML (RtiPeer names profiles of its own QoS
# library). Both are complete on their own apart from the base profiles they name.
EXTRA_PROFILES = """
    <!-- An RTI writer with RTI's default QoS, as a Shapes Demo publisher that was left at its defaults:
         reliable, volatile, keep last 1, XCDR1. -->
    <qos_profile name="ShapesDemoWriter">
      <datawriter_qos/>
    </qos_profile>

    <!-- A reader of our opt-in LidarAsync writer. Latency budget is a request-offered policy: that writer offers
         1 ms (a budget above zero makes Cyclone hand the sending to a separate thread: RTI's asynchronous
         publisher), so a reader must request at least that. RTI's default (and ROS 2's, and RViz2's) is 0: such a
         reader never matches it; the writer reports "incompatible QoS offered to a reader: LATENCY_BUDGET". -->
    <qos_profile name="LidarReader" base_name="ReliableReader">
      <datareader_qos>
        <latency_budget><duration><sec>0</sec><nanosec>100000000</nanosec></duration></latency_budget>
      </datareader_qos>
    </qos_profile>
"""


@pytest.fixture(scope="module")
def rti_xml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    text = RTI_XML.read_text()
    start = text.index('<qos_library name="RtiPeerQos">')
    end = text.index("</qos_library>", start)  # after the base profiles: RTI resolves base names in file order
    path = tmp_path_factory.mktemp("rti") / "automotive_rti_lidar.xml"
    path.write_text(text[:end] + EXTRA_PROFILES + text[end:])
    return path


def test_rti_shapes_demo_writer_draws_a_sphere_until_it_leaves(apps, domain_id: int,  # type: ignore[no-untyped-def]
                                                               bus: Databus, rti_xml: Path) -> None:
    clouds = Clouds(bus)
    lidar = apps.start("lidar", "--domain", str(domain_id), "-D", "config.noise=0")
    lidar.wait_for(r"frame \d+:")  # up, its Circle reader made: the peer's 15 s below are discovery's alone
    with RtiPeer(domain_id, writers={"Circle": "ShapesDemoWriter"}, xml=rti_xml) as peer:
        peer.wait_for_readers("Circle")
        lidar.wait_for(r"\[Circle\] reader matched a writer")  # both sides matched: the sample is not dropped
        # ShapeTypeExtended: fillKind and angle follow the base members; our ShapeType reader ignores them.
        peer.write("Circle", {"color": "ORANGE", "x": circle(4, 0)[0], "y": circle(4, 0)[1], "shapesize": 60,
                              "fillKind": 2, "angle": 45.0})
        lidar.wait_for(r"shape ORANGE appeared at \(216, 135\), size 60")
        orange = points_of(clouds.after(time.time(), 1)[0], SHAPE_RGB["ORANGE"])
        assert len(orange) > 20
        assert np.allclose(np.linalg.norm(orange - np.array([4.0, 0.0, 1.0]), axis=1), 1.0, atol=1e-3)
    # The RTI participant is gone: the instance has no writers left.
    lidar.wait_for(r"shape ORANGE removed \((no writers left|disposed)\)")
    assert len(points_of(clouds.after(time.time(), 1)[0], SHAPE_RGB["ORANGE"])) == 0


def test_rti_dispose_removes_the_sphere(apps, domain_id: int, bus: Databus) -> None:  # type: ignore[no-untyped-def]
    # With RTI's default QoS a dispose carries only the MD5 key hash of the colour (its key can be 128 characters
    # long, so the hash is not the key itself), and Cyclone drops such a message ("keyhash is MD5 and can't be
    # converted to key value"): a circle disposed in RTI Shapes Demo stays in our scan until its writer leaves.
    # The peer's own writer profile serializes the key with its disposals, which Cyclone understands.
    clouds = Clouds(bus)
    lidar = apps.start("lidar", "--domain", str(domain_id), "-D", "config.noise=0")
    lidar.wait_for(r"frame \d+:")  # up, its Circle reader made: the peer's 15 s below are discovery's alone
    with RtiPeer(domain_id, writers=["Circle"]) as peer:
        peer.wait_for_readers("Circle")
        lidar.wait_for(r"\[Circle\] reader matched a writer")
        # The lidar's reader is best effort: a sample that reaches it before its side of the match is complete is
        # lost (seen once for CYAN), so the circles are written until both appear.
        deadline = time.monotonic() + 30
        while lidar.count(r"shape (CYAN|RED) appeared") < 2 and time.monotonic() < deadline:
            peer.write("Circle", {"color": "CYAN", "x": circle(0, 3)[0], "y": circle(0, 3)[1], "shapesize": 60})
            peer.write("Circle", {"color": "RED", "x": circle(0, -3)[0], "y": circle(0, -3)[1], "shapesize": 60})
            lidar.wait_for_more(r"frame \d+:", 1)
        lidar.wait_for(r"shape CYAN appeared at \(120, 216\), size 60")
        lidar.wait_for(r"shape RED appeared")
        output = peer.output("Circle")
        output.clear_members()
        output.instance.set_dictionary({"color": "CYAN"})
        output.write(action="dispose")
        lidar.wait_for(r"shape CYAN removed \(disposed\)")
        for cloud in clouds.after(time.time()):
            assert len(points_of(cloud, SHAPE_RGB["CYAN"])) == 0 and len(points_of(cloud, SHAPE_RGB["RED"])) > 0


def test_our_shapes_publisher_reaches_a_shapes_demo_reader(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    # BestEffortReader: RTI's default reader QoS apart from history (best effort; XCDR1 only, as RTI Connext 6).
    with RtiPeer(domain_id, readers={"Circle": "BestEffortReader"}) as peer:
        shapes = apps.start("shapes", "publish", "--color", "PURPLE", "--shapesize", "45", "--domain", str(domain_id))
        shapes.wait_for(r"publishing PURPLE Circle")  # up: the peer's 15 s below are discovery's alone
        peer.wait_for_writers("Circle")
        samples = peer.take_until("Circle", 5, accept=lambda s: s["color"] == "PURPLE")
    assert len(samples) >= 5  # the last take may bring more than the fifth
    assert all(s["shapesize"] == 45 and 23 <= s["x"] <= 217 and 23 <= s["y"] <= 247 for s in samples)
    assert len({(s["x"], s["y"]) for s in samples}) > 1  # it moves


def cloud_dict(sample: dict[str, Any]) -> dict[str, Any]:
    return {key: value for key, value in sample.items() if key != "data_"}


@pytest.mark.parametrize("our_profile,rti_profile", [
    ("Lidar", "ReliableReader"),  # the shipped profile; a reader as the original applications and RViz2 have it
    ("LidarAsync", "LidarReader"),  # the opt-in asynchronous writer: the reader must accept its latency budget
])
def test_rti_reader_receives_our_point_clouds_intact(apps, domain_id: int, bus: Databus,  # type: ignore[no-untyped-def]
                                                     rti_xml: Path, our_profile: str, rti_profile: str) -> None:
    writer = bus.writer("Circle", ShapeType, "Shapes")
    lidar = apps.start("lidar", "--domain", str(domain_id), "-D", "config.noise=0",
                       "-D", f"qos.Lidar.Profile={our_profile}")
    wait_until(lambda: len(matched_subscriptions(writer)) == 1, what="the LiDAR's Circle reader")
    # Best effort, as Shapes Demo's reader: until the LiDAR has matched the writer itself, its samples are lost.
    write_until(lidar, r"shape GREEN appeared", lambda: writer.write(ShapeType("GREEN", *circle(-2, 3), 75)))
    # Without noise the LiDAR's frames of this scene are exactly what the same scene renders here.
    scene = LidarScene(ScanGrid(), noise_m=0.0)
    scene.update_shape("GREEN", *circle(-2, 3), 75)
    expected = scene.render_bytes()
    xyz_expected, rgb_expected = decode_point_cloud2(scene.point_cloud2(0, 0))
    assert len(with_colour(xyz_expected, rgb_expected, SHAPE_RGB["GREEN"])) > 20

    with RtiPeer(domain_id, readers={"Lidar": rti_profile}, xml=rti_xml) as peer:
        peer.wait_for_writers("Lidar")
        lidar.wait_for(r"\[rt/LidarTopic\] writer matched a reader")
        clouds = peer.take_until("Lidar", 3)
    assert len(clouds) >= 3  # a take may bring more than asked for
    now = time.time()
    for cloud in clouds:
        header = cloud_dict(cloud)
        stamp = header.pop("header_")
        assert stamp["frame_id_"] == "map"
        assert abs(stamp["stamp_"]["sec_"] + stamp["stamp_"]["nanosec_"] * 1e-9 - now) < 30
        assert header == {
            "height_": 64, "width_": 180, "is_bigendian_": False, "point_step_": 16, "row_step_": 180 * 16,
            "is_dense_": True, "fields_": [{"name_": name, "offset_": offset, "datatype_": FLOAT32, "count_": 1}
                                           for name, offset in (("x", 0), ("y", 4), ("z", 8), ("rgb", 12))]}
        data = bytes(cloud["data_"])
        assert data == expected  # every byte as rendered
        msg = PointCloud2_.deserialize(scene.point_cloud2(0, 0).serialize())
        msg.data_ = data
        xyz, rgb = decode_point_cloud2(msg)
        assert np.array_equal(xyz, xyz_expected) and np.array_equal(rgb, rgb_expected)
    assert "incompatible QoS" not in lidar.output
    assert re.search(r"frame \d+: 11520 points, 1 sphere\(s\) GREEN", lidar.wait_for(r"frame \d+: .*GREEN"))
