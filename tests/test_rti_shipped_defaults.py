"""The system as shipped, heard by RTI Connext readers that use RTI's default QoS (tests/rti_peer.py, DefaultReader).

Every application runs with its shipped properties file (only the domain id, and the vision period to reach the
first driver alert sooner, are changed), and an RTI participant with the original type definitions reads every
flow with the QoS an RTI application gets when it names no profile: best effort, volatile, keep last 1, latency
budget 0, XCDR1. This is how a user meets the system with RTI's tools.
"""

from __future__ import annotations

import pytest

pytest.importorskip("rticonnextdds_connector")

from rti_peer import RtiPeer

from automotive.sim.lfsr import FramePattern

FULL_FRAME = 1366 * 768 * 4
FLOWS = ["Vision", "SensorObjects", "PlatformControl", "PlatformStatus", "Alerts", "Lidar", "Camera"]


def test_every_flow_of_the_shipped_system_reaches_default_rti_readers(apps, domain_id: int) -> None:  # type: ignore[no-untyped-def]
    domain = ("--domain", str(domain_id))
    with RtiPeer(domain_id, readers={flow: "DefaultReader" for flow in FLOWS}) as peer:
        for name in ("vehicle_platform", "collision_avoidance", "sensor_fusion", "lidar", "camera_pub"):
            apps.start(name, *domain)
        apps.start("hmi", "--ui", "console", *domain)
        # 20 ms instead of 100 ms a row: the data's first tall object (row 95) comes after 2 s instead of 10 s.
        apps.start("vision", *domain, "-D", "config.pubInterval=20")
        first = {}
        for flow in FLOWS:
            peer.wait_for_writers(flow, timeout=30)
            samples = peer.take_until(flow, 1, timeout=30)
            assert samples, f"the RTI default reader of {flow} received nothing"
            first[flow] = samples[0]

        cloud = first["Lidar"]
        assert cloud["header_"]["frame_id_"] == "map"
        assert len(cloud["data_"]) == cloud["row_step_"] * cloud["height_"] == 11520 * 16
        frame = first["Camera"]
        assert frame["id"] == 1 and len(frame["data"]) == FULL_FRAME
        assert FramePattern(FULL_FRAME).matches(frame["seqnum"], bytes(frame["data"]))

        alerts = peer.take_until("Alerts", 1, timeout=30,
                                 accept=lambda alert: bool(alert["driverAttention"]))
        assert alerts, "the driver-attention alert did not reach the RTI reader"
