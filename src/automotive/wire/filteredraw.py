"""Content filters on serialized samples: a :class:`~automotive.wire.rawsample.RawReader` that delivers only the
samples its filter (automotive.bus.contentfilter) accepts. Used by the recorder and the bridge.

Each sample of data is decoded with its type's decoder and checked (automotive.bus.validation) before the filter sees
it, as a CheckedReader does: a sample that does not decode or fails its checks is reported once per kind
(automotive.bus.badsamples) and left out. Disposals and unregistrations pass for the instances whose data passed.

    raw = filtered_raw_reader(reader, app.filters.predicate(topic, data_type))   # a RawReader when no filter
"""

from __future__ import annotations

from typing import Any

from cyclonedds.core import InstanceState
from cyclonedds.sub import DataReader

from automotive.bus import validation
from automotive.bus.badsamples import BadSample
from automotive.bus.checkedreader import decoder, report_bad_sample, undecodable
from automotive.bus.contentfilter import Predicate, SeenInstances, evaluate
from automotive.cyclone.bounds import type_name
from automotive.wire.rawsample import Buffer, RawReader, RawSample, SampleKind


class FilteredRawReader(RawReader):
    """A :class:`RawReader` that delivers only the samples matching its filter (see the module's doc)."""

    def __init__(self, reader: DataReader[Any], content_filter: Predicate, zero_copy: bool = True):
        super().__init__(reader, zero_copy)
        self.content_filter = content_filter
        self.filtered_out = 0  # samples of data that did not match
        self.bad = 0  # samples of data that did not decode or failed their checks
        self._seen = SeenInstances()

    def samples_of(self, data: Buffer, info: Any, whole_key_sample: bool = False) -> list[RawSample]:
        kept = []
        for sample in super().samples_of(data, info, whole_key_sample):
            if sample.kind is SampleKind.DATA:
                decoded = self._decoded(sample)
                passed = decoded is not None and self._matches(sample, decoded)
                # A raw reader receives an instance's end as a sample of its own (below), never on a data sample.
                self._seen.data(sample.instance, passed, InstanceState.Alive)
                if passed:
                    kept.append(sample)
            elif self._seen.state_change(sample.instance):
                kept.append(sample)
        return kept

    def _decoded(self, sample: RawSample) -> Any:
        """The sample decoded and checked; None (reported) when it cannot be decoded or fails its checks."""
        problem: BadSample | None
        try:
            decoded = decoder(self.data_type)(bytes(sample.data))
        except Exception as error:  # whatever a decoder raises for bytes it cannot decode
            decoded, problem = None, undecodable(error, f"a sample that decodes as {type_name(self.data_type)}")
        else:
            problem = validation.check(decoded)
        if problem is None:
            return decoded
        self._report(sample, problem)
        return None

    def _matches(self, sample: RawSample, decoded: Any) -> bool:
        verdict = evaluate(self.content_filter, decoded)
        if isinstance(verdict, BadSample):
            self._report(sample, verdict)
            return False
        self.filtered_out += not verdict
        return verdict

    def _report(self, sample: RawSample, problem: BadSample) -> None:
        self.bad += 1
        report_bad_sample(self.reader, self._writer_names, problem, sample.writer)


def filtered_raw_reader(reader: DataReader[Any], content_filter: Predicate | None,
                        zero_copy: bool = True) -> RawReader:
    """A RawReader of ``reader``, filtered when ``content_filter`` is given."""
    if content_filter is None:
        return RawReader(reader, zero_copy)
    return FilteredRawReader(reader, content_filter, zero_copy)
