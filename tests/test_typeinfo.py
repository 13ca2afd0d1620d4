"""The types' XTypes type information, made at build time (automotive/types/typeinfo.py) and announced from that table
(automotive.cyclone.typeinfo): the very bytes Cyclone's builder makes, and what another tool learns the type from."""

from __future__ import annotations

import subprocess
import time

import pytest
from cyclonedds.idl._support import Endianness
from cyclonedds.idl._xt_builder import XTBuilder
from dds_helpers import CYCLONEDDS_CLI, make_bus

from automotive.cyclone import gate, typeinfo
from automotive.types.Platform import PlatformStatus
from automotive.types.typeinfo import CYCLONEDDS_VERSION, TYPE_INFO


def cyclones_own(data_type: type) -> tuple[bytes, bytes]:
    """What Cyclone DDS Python's IDL.fill_type_data computes for ``data_type``: its builder, then its serializer."""
    info, mapping = XTBuilder.process_type(data_type)
    return (info.serialize(endianness=Endianness.Little, use_version_2=True)[4:],
            mapping.serialize(endianness=Endianness.Little, use_version_2=True)[4:])


@pytest.mark.fast
def test_the_table_was_made_by_the_installed_cyclonedds_and_is_in_use() -> None:
    assert CYCLONEDDS_VERSION == gate.cyclone_version() == gate.TESTED_VERSION
    assert all(typeinfo.installed(data_type) for data_type in TYPE_INFO)  # tests/conftest.py started the fast paths


@pytest.mark.fast
@pytest.mark.parametrize("data_type", list(TYPE_INFO), ids=lambda data_type: data_type.__idl_typename__)
def test_the_table_holds_what_cyclones_builder_makes_of_the_type(data_type: type) -> None:
    assert TYPE_INFO[data_type] == cyclones_own(data_type)


@pytest.mark.fast
def test_a_topic_announces_the_tables_bytes_and_whoever_asks_for_objects_gets_cyclones_own(domain_id: int) -> None:
    bus = make_bus(domain_id)
    try:
        bus.topic("PlatformStatus", PlatformStatus)
        idl = PlatformStatus.__idl__  # type: ignore[attr-defined]
        assert idl._xt_bytedata == TYPE_INFO[PlatformStatus]
        info = idl.get_type_info()  # built by Cyclone on this call
        assert info.serialize(endianness=Endianness.Little, use_version_2=True)[4:] == TYPE_INFO[PlatformStatus][0]
        assert idl.get_type_id() == info.complete.typeid_with_size.type_id
        assert idl._xt_bytedata == TYPE_INFO[PlatformStatus]
    finally:
        bus.close()


def test_cyclones_own_tool_learns_the_type_from_the_announced_bytes(domain_id: int) -> None:
    """`cyclonedds typeof` asks the writer's participant for the type (XTypes type lookup) and prints it as IDL: what it
    gets is the table's TypeMapping. The tool scans for a fixed time and prints nothing when the scan found no writer
    yet (a loaded machine): scanned again until it prints, within a bound."""
    members = ["Common::POSIXTimestamp timestamp;", "float vehSpd;", "Common::IndicatorStatusEnum blinkerStatus;",
               "float posGasPedal;", "float velocity;", "float yawRate;", "float vehicleSteerAngle;"]
    bus = make_bus(domain_id)
    try:
        bus.writer("PlatformStatus", PlatformStatus, "Platform")
        deadline = time.monotonic() + 60
        output = ""
        while "struct PlatformStatus {" not in output and time.monotonic() < deadline:
            output = subprocess.run([CYCLONEDDS_CLI, "typeof", "PlatformStatus", "-i", str(domain_id), "-r", "3s",
                                     "--suppress-progress-bar", "--color", "none"],
                                    capture_output=True, text=True, timeout=60).stdout
    finally:
        bus.close()
    body = [line.strip() for line in output.splitlines()]
    assert "struct PlatformStatus {" in body and all(member in body for member in members), output
