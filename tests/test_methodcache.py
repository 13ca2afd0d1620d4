"""The dataclasses' methods compiled once per machine (automotive.methodcache): the same classes, whatever the file."""

from __future__ import annotations

import dataclasses
import marshal
from pathlib import Path

import pytest

from automotive import methodcache
from automotive.methodcache import ENVIRONMENT, FILENAME, cache_directory, compiled_once


def make_classes() -> tuple[type, type]:
    """Two classes made afresh at each call, from the same source: the methods dataclasses writes for them."""
    @dataclasses.dataclass(frozen=True, order=True)
    class Reading:
        sensor: int
        values: tuple[float, ...] = ()

    @dataclasses.dataclass
    class Track:
        name: str
        points: list[int] = dataclasses.field(default_factory=list)
        weight: float = dataclasses.field(default=1.0, compare=False)

    return Reading, Track


def check_behaviour(reading: type, track: type) -> None:
    """What the generated __init__, __repr__, __eq__, ordering and frozen setattr do."""
    first, second = reading(1, (2.0,)), reading(2)
    assert first < second and first == reading(1, (2.0,)) and hash(first) == hash(reading(1, (2.0,)))
    assert repr(second) == "make_classes.<locals>.Reading(sensor=2, values=())"
    with pytest.raises(dataclasses.FrozenInstanceError):
        first.sensor = 3  # type: ignore[misc]
    one, other = track("a"), track("a", weight=5.0)
    assert one == other and one.points is not other.points  # compare=False; a list of its own each
    one.points.append(1)
    assert one != other and repr(one) == "make_classes.<locals>.Track(name='a', points=[1], weight=1.0)"
    with pytest.raises(TypeError):
        track()


def test_the_next_start_of_the_same_classes_compiles_nothing(tmp_path: Path) -> None:
    with compiled_once(str(tmp_path)) as methods:
        first = make_classes()
    assert methods is not None and methods.compiled > 0
    assert (tmp_path / FILENAME).is_file()
    with compiled_once(str(tmp_path)) as methods:  # as the next program's start reads the file
        second = make_classes()
    assert methods is not None and methods.compiled == 0 and len(methods.codes) > 0
    check_behaviour(*first)
    check_behaviour(*second)


def test_only_the_block_compiles_through_the_cache(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError):
        with compiled_once(str(tmp_path)):
            assert "exec" in vars(dataclasses)
            with compiled_once(str(tmp_path / "inner")) as inner:  # a block inside another leaves it to the outer
                assert inner is None
            raise RuntimeError("an import that fails")
    assert "exec" not in vars(dataclasses)
    assert not (tmp_path / "inner").exists()


@pytest.mark.parametrize("content", [
    b"", b"not marshal data", marshal.dumps(("another Python", {})), marshal.dumps([1, 2, 3]), "truncated",
    "not code"], ids=["empty", "garbage", "another-build", "another-shape", "truncated", "not-code"])
def test_a_file_that_cannot_be_used_counts_as_empty_and_is_written_again(tmp_path: Path, content: bytes | str) -> None:
    path = tmp_path / FILENAME
    if content == "truncated":
        with compiled_once(str(tmp_path)):
            make_classes()
        content = path.read_bytes()[:-100]
    elif content == "not code":  # the right build, every source there, but numbers where the code should be
        with compiled_once(str(tmp_path)) as written:
            make_classes()
        assert written is not None
        content = marshal.dumps((methodcache.BUILD, dict.fromkeys(written.codes, 5)))
    path.write_bytes(content)  # type: ignore[arg-type]
    with compiled_once(str(tmp_path)) as methods:
        check_behaviour(*make_classes())
    assert methods is not None and methods.compiled > 0
    with compiled_once(str(tmp_path)) as methods:
        check_behaviour(*make_classes())
    assert methods is not None and methods.compiled == 0


def test_a_cache_that_cannot_be_written_leaves_the_classes_as_they_were(tmp_path: Path) -> None:
    blocked = tmp_path / "a file, not a directory"
    blocked.write_text("")
    with compiled_once(str(blocked / "automotive")) as methods:
        check_behaviour(*make_classes())
    assert methods is not None and methods.compiled > 0
    assert [path.name for path in tmp_path.iterdir()] == [blocked.name]  # no temporary file left behind


def test_off_compiles_as_python_does(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(ENVIRONMENT, "off")
    with compiled_once(str(tmp_path)) as methods:
        assert methods is None and "exec" not in vars(dataclasses)
        check_behaviour(*make_classes())
    assert list(tmp_path.iterdir()) == []


def test_the_cache_directory_follows_the_xdg_specification(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache_directory() == str(tmp_path / "automotive")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    for ignored in ("relative/cache", ""):
        monkeypatch.setenv("XDG_CACHE_HOME", ignored)
        assert cache_directory() == str(tmp_path / "home" / ".cache" / "automotive")
    monkeypatch.setenv("HOME", "no/home")  # no absolute home: no cache (not a folder named "no" here)
    assert cache_directory() is None


def test_a_file_grown_past_its_bound_keeps_what_the_writer_used(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    stale = {f"def stale_{n}(): pass": compile(f"def stale_{n}(): pass", "<string>", "exec") for n in range(50)}
    (tmp_path / FILENAME).write_bytes(marshal.dumps((methodcache.BUILD, stale)))
    monkeypatch.setattr(methodcache, "MAX_METHODS", 40)
    with compiled_once(str(tmp_path)) as methods:
        check_behaviour(*make_classes())
    assert methods is not None and methods.compiled > 0
    with compiled_once(str(tmp_path)) as methods:
        check_behaviour(*make_classes())
    assert methods is not None and methods.compiled == 0 and set(methods.codes) == set(methods.used)
    assert not set(stale) & set(methods.codes)
