"""Which writer an EXCLUSIVE reader follows (redundant mode): one line at each change of owner.

With exclusive ownership a reader takes only the samples of the strongest live writer of an instance; when that
writer's liveliness is lost, the next strongest one's samples come through. The owner of a sample is its
``sample_info.publication_handle``; the writer's discovery data names it (entity name: the instance's name) and gives
its strength.
"""

from __future__ import annotations

import logging
from typing import Any

from cyclonedds.core import DDSException
from cyclonedds.qos import Policy
from cyclonedds.sub import DataReader


class OwnerTracker:
    """Follows the writer of the samples an application takes; does nothing for a SHARED reader."""

    def __init__(self, reader: DataReader[Any], log: logging.Logger):
        self.reader = reader
        self.log = log
        self.topic_name = reader.topic.get_name()
        self.enabled = Policy.Ownership.Exclusive in reader.get_qos()
        self.owner: int | None = None
        self.owner_name = ""
        self.last_stamp_ns = 0

    def describe(self, handle: int) -> str:
        """'<instance name> (strength N)' from the writer's discovery data."""
        try:
            qos = self.reader.get_matched_publication_data(handle).qos
        except DDSException:  # already gone
            return f"writer {handle:x}"
        name = qos[Policy.EntityName].name if Policy.EntityName in qos else f"writer {handle:x}"
        strength = qos[Policy.OwnershipStrength].strength if Policy.OwnershipStrength in qos else 0
        return f"{name} (strength {strength})"

    def follow(self, sample: Any) -> bool:
        """Note the writer of a valid sample; report and return True when it is not the previous sample's writer."""
        if not self.enabled:
            return False
        info = sample.sample_info
        changed = info.publication_handle != self.owner
        if changed:
            name = self.describe(info.publication_handle)
            if self.owner is None:
                self.log.info("[%s] owner: %s", self.topic_name, name)
            else:
                # Source timestamps: the gap between the writers' samples, whenever this reader takes them.
                gap_ms = (info.source_timestamp - self.last_stamp_ns) / 1e6
                self.log.warning("[%s] owner changed: %s -> %s, %.0f ms after the last sample of the previous owner",
                                 self.topic_name, self.owner_name, name, gap_ms)
            self.owner, self.owner_name = info.publication_handle, name
        self.last_stamp_ns = info.source_timestamp
        return changed
