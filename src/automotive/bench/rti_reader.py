"""An RTI Connext reader of PlatformControl as an outside system in redundant mode has it: EXCLUSIVE ownership and a
300 ms liveliness lease requested (docs/redundancy.md, "Following it from outside"), on loopback.

    python -m automotive.bench.rti_reader --domain 87

Run by ``automotive bench failover --sequences ...`` in a process of its own. Through RTI Connector for Python (pip
``rticonnextdds-connector``, imported only here). Prints ``rti reader running``, ``matched N`` at each change of the
number of matched writers, then one JSON line per sample taken: ``{"t": reception (time.time), "sample_id": N,
"src_ns": the writer's source timestamp}``. RTI's own log messages go to stderr, so that they never cut into those
lines. Ends on SIGTERM or SIGINT.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time
from collections.abc import Callable
from typing import Any

LEASE_NS = 300_000_000

# The original example's type, as RTI declares it (appendable; helper types at the root), and the reader's QoS.
_XML = """<dds>
<types>
  <struct name="POSIXTimestamp" extensibility="appendable">
    <member name="s" type="long"/><member name="ns" type="long"/>
  </struct>
  <enum name="IndicatorStatusEnum">
    <enumerator name="INDICATOR_OFF" value="0"/><enumerator name="INDICATOR_LEFT" value="1"/>
    <enumerator name="INDICATOR_RIGHT" value="2"/><enumerator name="INDICATOR_HAZARD" value="3"/>
  </enum>
  <module name="Platform">
    <struct name="PlatformControl" extensibility="appendable">
      <member name="sample_id" type="long"/>
      <member name="timestamp" type="nonBasic" nonBasicTypeName="POSIXTimestamp"/>
      <member name="vehicleSteerAngle" type="float"/>
      <member name="speed" type="float"/>
      <member name="blinkerStatus" type="nonBasic" nonBasicTypeName="IndicatorStatusEnum"/>
    </struct>
  </module>
</types>
<domain_library name="Domains">
  <domain name="Automotive" domain_id="0">
    <register_type name="Platform::PlatformControl" type_ref="Platform::PlatformControl"/>
    <topic name="PlatformControl" register_type_ref="Platform::PlatformControl"/>
  </domain>
</domain_library>
<domain_participant_library name="Participants">
  <domain_participant name="Reader" domain_ref="Domains::Automotive" domain_id="DOMAIN_ID">
    <domain_participant_qos>
      <transport_builtin><mask>UDPv4</mask></transport_builtin>
      <discovery>
        <initial_peers><element>udpv4://127.0.0.1</element></initial_peers>
        <multicast_receive_addresses/>
      </discovery>
      <property><value>
        <element><name>dds.transport.UDPv4.builtin.ignore_loopback_interface</name><value>0</value></element>
        <element><name>dds.transport.UDPv4.builtin.parent.allow_interfaces_list</name><value>127.0.0.1</value></element>
      </value></property>
      <participant_name><name>bench-rti-reader</name></participant_name>
      <database>
        <shutdown_cleanup_period><sec>0</sec><nanosec>10000000</nanosec></shutdown_cleanup_period>
      </database>
    </domain_participant_qos>
    <subscriber name="Sub">
      <data_reader name="PlatformControl" topic_ref="PlatformControl">
        <datareader_qos>
          <reliability><kind>BEST_EFFORT_RELIABILITY_QOS</kind></reliability>
          <history><kind>KEEP_LAST_HISTORY_QOS</kind><depth>100</depth></history>
          <ownership><kind>EXCLUSIVE_OWNERSHIP_QOS</kind></ownership>
          <liveliness>
            <kind>AUTOMATIC_LIVELINESS_QOS</kind>
            <lease_duration><sec>0</sec><nanosec>LEASE_NS</nanosec></lease_duration>
          </liveliness>
        </datareader_qos>
      </data_reader>
    </subscriber>
  </domain_participant>
</domain_participant_library>
</dds>"""

MISSING = ("the RTI reader needs RTI Connector for Python: pip install rticonnextdds-connector "
           "(the project's test extra: pip install -e .[test])")


def own_lines() -> Callable[[str], None]:
    """This program's lines, each in one write; whatever else writes to file descriptor 1 (RTI's log messages, a
    piece at a time) goes to stderr from now on."""
    stdout = os.dup(1)
    os.dup2(2, 1)

    def say(line: str) -> None:
        os.write(stdout, (line + "\n").encode())

    return say


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m automotive.bench.rti_reader", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--domain", type=int, required=True, help="DDS domain id")
    args = parser.parse_args(argv)
    try:
        import rticonnextdds_connector as rti  # type: ignore[import-untyped]
    except ImportError:
        print(MISSING, file=sys.stderr)
        return 2
    say = own_lines()
    xml = _XML.replace("DOMAIN_ID", str(args.domain)).replace("LEASE_NS", str(LEASE_NS))
    connector = rti.Connector("Participants::Reader", f'str://"{xml}"')
    stopping: list[bool] = []

    def stop(signum: int, frame: Any) -> None:
        stopping.append(True)

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    reader = connector.get_input("Sub::PlatformControl")
    matched = 0
    next_match_check = 0.0
    say("rti reader running")
    try:
        while not stopping:
            try:
                reader.wait(50)
            except rti.TimeoutError:
                pass
            if time.monotonic() >= next_match_check:
                next_match_check = time.monotonic() + 0.25
                try:
                    count = len(reader.matched_publications)
                except ValueError:  # Connector 1.2.4 once gave JSON it could not parse (as a writer went): next time
                    count = matched
                if count != matched:
                    matched = count
                    say(f"matched {count}")
            reader.take()
            now = time.time()
            for sample in reader.samples.valid_data_iter:
                say(json.dumps({"t": now, "sample_id": int(sample.get_number("sample_id")),
                                "src_ns": int(sample.info["source_timestamp"])}))
            reader.return_samples()
    finally:
        connector.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
