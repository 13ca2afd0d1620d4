"""Reading what a child program writes while it runs: its status records (automotive.bus.stats.Follower, what the
benchmarks wait on) and its output lines (automotive.tools.support.children.Child.wait_for_line). Both are read as
they come, each record and line once, however long the child has been writing."""

from __future__ import annotations

import json
import logging
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from automotive.bus import stats
from automotive.tools.support.children import Child


def test_a_follower_reads_each_record_once_as_it_is_appended(tmp_path: Path) -> None:
    path = tmp_path / "app.jsonl"
    follower = stats.Follower(path)
    assert follower.records() == []  # not written yet
    writer = stats.Stats(path, "app")
    writer.record("ready")
    writer.record("sample", n=1)
    assert [record["kind"] for record in follower.records()] == ["ready", "sample"]
    writer.record("sample", n=2)
    writer.close()
    assert [record["n"] for record in follower.records("sample")] == [1, 2]
    assert follower.records("matched") == []
    assert [record["kind"] for record in follower.records()] == ["ready", "sample", "sample"]
    assert list(stats.read(path, "sample")) == follower.records("sample")


@pytest.mark.fast
def test_records_of_a_wake_up_wait_until_its_outputs_are_written_and_keep_their_time(tmp_path: Path) -> None:
    path = tmp_path / "app.jsonl"
    follower = stats.Follower(path)
    writer = stats.Stats(path, "app")
    others: list[None] = []
    with writer.deferred() as write_records:
        writer.record("take", n=1)
        made = time.time()
        assert follower.records() == []  # held back until the wake-up's outputs are written
        # another thread's record (a listener's) is written at once
        thread = threading.Thread(target=lambda: others.append(writer.record("matched")))
        thread.start()
        thread.join()
        assert [record["kind"] for record in follower.records()] == ["matched"]
        write_records()
        assert [record["kind"] for record in follower.records()] == ["matched", "take"]
        # the time it was made, not written (the record keeps it to the microsecond, rounded)
        assert follower.records("take")[0]["t"] <= made + 1e-6
        writer.record("take", n=2)  # left at the end: written then
    writer.record("sample")  # outside: written at once
    assert [record.get("n") for record in follower.records("take")] == [1, 2]
    assert follower.records()[-1]["kind"] == "sample"
    writer.close()


@pytest.mark.fast
def test_a_record_held_back_is_written_before_the_next_line_its_thread_says(tmp_path: Path) -> None:
    """Whoever reads a line finds the records made before it (the HMI records a lost alert source, then says it)."""
    path = tmp_path / "app.jsonl"
    follower = stats.Follower(path)
    writer = stats.Stats(path, "app")
    log = logging.getLogger("test_status_records.said")
    said: list[int] = []
    handler = logging.Handler()
    handler.emit = lambda record: said.append(len(follower.records()))  # type: ignore[method-assign]
    log.addHandler(handler)
    log.propagate = False
    try:
        with writer.deferred(log):
            writer.record("source", alive=False)
            log.warning("alert source LOST")
            writer.record("take")
        assert said == [1] and [record["kind"] for record in follower.records()] == ["source", "take"]
        assert handler.filters == []  # the filter goes with the loop
    finally:
        log.removeHandler(handler)
        writer.close()


def test_a_line_still_being_written_waits_and_what_is_not_a_record_is_passed_over(tmp_path: Path) -> None:
    path = tmp_path / "app.jsonl"
    follower = stats.Follower(path)
    first = json.dumps({"t": 1.0, "kind": "window", "samples": 3})
    with path.open("w") as stream:
        stream.write(f"{first}\nnot json\n[1, 2]\n\xff\n")
        stream.write('{"t": 2.0, "kind": "win')
    assert follower.records() == [json.loads(first)]
    with path.open("a") as stream:
        stream.write('dow", "samples": 4}\n')
    assert [record["samples"] for record in follower.records("window")] == [3, 4]
    path.write_text(json.dumps({"t": 3.0, "kind": "totals"}) + "\n")  # written anew, shorter: read from its start
    assert [record["kind"] for record in follower.records()] == ["totals"]


@pytest.fixture
def counter() -> Iterator[Child]:
    """A child that prints 'line 1' to 'line 6', then waits until its input closes."""
    child = Child("counter", [sys.executable, "-c", "import sys\nfor n in range(1, 7): print(f'line {n}')\n"
                                                    "sys.stdin.read()"], stdin=True)
    yield child
    child.stop()


def test_wait_for_line_counts_matches_from_a_line_on(counter: Child) -> None:
    line, match = counter.wait_for_line(r"line (\d)", count=3)
    assert (line.text, match.group(1)) == ("line 3", "3")
    assert counter.wait_for_line(r"line [246]", count=2, since=2)[0].text == "line 6"  # lines 4 and 6 from line 3 on
    assert counter.wait_for(r"line 1") == "line 1"
    with pytest.raises(AssertionError, match=r"no 7x /line/ within 0 s"):
        counter.wait_for(r"line", count=7, timeout=0.3)
    counter.process.stdin.close()  # type: ignore[union-attr]
    with pytest.raises(AssertionError, match=r"counter ended \(exit 0\) before 1x /line 7/"):
        counter.wait_for(r"line 7")
