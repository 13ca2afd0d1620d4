"""QoS profiles from an OMG DDS-XML file, checked by name before Cyclone's QosProvider is asked."""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from pathlib import Path

from cyclonedds.qos import DataReaderQos, DataWriterQos, Policy
from cyclonedds.qos_provider import QosProvider

from automotive.bus.errors import ConfigError
from automotive.bus.properties import Properties

# RTI Connext 6 readers accept XCDR1 by default, not Cyclone's XCDR2 default for appendable types; our writers
# therefore write XCDR1 and our readers accept both.
WRITER_REPRESENTATION = Policy.DataRepresentation(use_cdrv0_representation=True)
READER_REPRESENTATION = Policy.DataRepresentation(use_cdrv0_representation=True, use_xcdrv2_representation=True)

# A profile every QoS file has, defined here: ROS 2's default QoS (rmw_qos_profile_default: reliable, volatile, keep
# last 10), that of /diagnostics (automotive.bus.diagnostics), so that rqt_robot_monitor, Foxglove and any ROS 2 node
# match it whatever QoS file the programs are given. A profile of the same name in the file takes its place.
ROS2_DEFAULT_PROFILE = "ROS2Default"
_ROS2_DEFAULT = (Policy.Reliability.Reliable(max_blocking_time=100_000_000), Policy.Durability.Volatile,
                 Policy.History.KeepLast(10))


def profile_name(props: Properties, role: str) -> str:
    """The QoS profile of an application's endpoint: ``qos.<role>.Profile``, else ``qos.Profile``, else the role."""
    return props.get_str(f"qos.{role}.Profile", None) or props.get_str("qos.Profile", role)


def _local_name(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


class QosProfiles:
    """The profiles of one QoS file, addressed as (library, profile)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.names = self._profile_names(self.path)
        try:
            self._provider = QosProvider(str(self.path))
        except Exception as error:  # Cyclone raises DDSException with its own wording
            raise ConfigError(f"{self.path}: Cyclone's QosProvider rejected the file ({error})") from None

    @staticmethod
    def _profile_names(path: Path) -> list[str]:
        try:
            root = ElementTree.parse(path).getroot()
        except FileNotFoundError:
            raise ConfigError(f"{path}: QoS file not found") from None
        except (OSError, ElementTree.ParseError) as error:
            raise ConfigError(f"{path}: not a readable QoS XML file ({error})") from None
        names = []
        for library in root:
            if _local_name(library.tag) != "qos_library":
                continue
            for profile in library:
                if _local_name(profile.tag) == "qos_profile":
                    names.append(f"{library.get('name')}::{profile.get('name')}")
        return names

    def key(self, library: str, profile: str) -> str:
        key = f"{library}::{profile}"
        if key not in self.names:
            raise ConfigError(f"{self.path}: no QoS profile '{key}' (available: {', '.join(self.names)})")
        return key

    def _builtin(self, library: str, profile: str) -> bool:
        """The built-in ROS 2 default profile, which the file does not define itself."""
        return profile == ROS2_DEFAULT_PROFILE and f"{library}::{profile}" not in self.names

    def writer_qos(self, library: str, profile: str) -> DataWriterQos:
        if self._builtin(library, profile):
            return DataWriterQos(*_ROS2_DEFAULT, WRITER_REPRESENTATION)
        base = self._provider.get_datawriter_qos(self.key(library, profile))
        return DataWriterQos(WRITER_REPRESENTATION, base=base)

    def reader_qos(self, library: str, profile: str) -> DataReaderQos:
        if self._builtin(library, profile):
            return DataReaderQos(*_ROS2_DEFAULT, READER_REPRESENTATION)
        base = self._provider.get_datareader_qos(self.key(library, profile))
        return DataReaderQos(READER_REPRESENTATION, base=base)

    def has(self, library: str, profile: str) -> bool:
        return f"{library}::{profile}" in self.names or profile == ROS2_DEFAULT_PROFILE

    def exclusive_writer(self, library: str, profile: str) -> bool:
        """True if the profile's writers have EXCLUSIVE ownership (and so need an ownership strength)."""
        return Policy.Ownership.Exclusive in self.writer_qos(library, profile)
