"""The .properties reader: each syntax form, typed getters and defaults, overrides, and malformed input."""

from __future__ import annotations

from pathlib import Path

import pytest

from automotive.bus.errors import ConfigError
from automotive.bus.properties import Properties, PropertyKeys

SAMPLE = r"""
# a comment
! another comment

config.domainId = 7
config.pubInterval: 250
config.sensorId 3
   topic.Vision=VisionTopic{trailing}
qos.Profile=
dataFile=data/vision.csv
long.value = first \
             second
escaped\:key = a\=b
config.ratio=0.5
config.enabled=yes
config.peers = 10.0.0.2, 10.0.0.3 ,,
""".format(trailing="   ")


@pytest.fixture
def props(tmp_path: Path) -> Properties:
    path = tmp_path / "app.properties"
    path.write_text(SAMPLE)
    return Properties.load(path)


def test_syntax_forms(props: Properties) -> None:
    assert props.get_int("config.domainId") == 7
    assert props.get_int("config.pubInterval") == 250
    assert props.get_int("config.sensorId") == 3
    assert props.get_str("topic.Vision") == "VisionTopic"
    assert props.get_str("qos.Profile") == ""
    assert props.get_str("long.value") == "first second"
    assert props.get_str("escaped:key") == "a=b"
    assert props.get_float("config.ratio") == 0.5
    assert props.get_bool("config.enabled") is True
    assert props.get_list("config.peers") == ["10.0.0.2", "10.0.0.3"]


def test_paths_resolve_against_the_file_folder(props: Properties, tmp_path: Path) -> None:
    assert props.get_path("dataFile") == tmp_path / "data" / "vision.csv"


def test_defaults(props: Properties) -> None:
    assert props.get_int("config.missing", 42) == 42
    assert props.get_str("config.missing", "x") == "x"
    assert props.get_bool("config.missing", False) is False
    assert props.get_list("config.missing", []) == []


def test_overrides_win_and_are_named_in_errors(props: Properties) -> None:
    props.override(["config.domainId=5", "config.pubInterval = abc"])
    assert props.get_int("config.domainId") == 5
    with pytest.raises(ConfigError, match=r"^-D: config.pubInterval = 'abc' is not an integer$"):
        props.get_int("config.pubInterval")
    with pytest.raises(ConfigError, match=r"-D 'nokey': expected key=value"):
        props.override(["nokey"])


def test_unused_keys_are_reported(props: Properties) -> None:
    props.get_int("config.domainId")
    assert "config.sensorId" in props.unused_keys()
    assert "config.domainId" not in props.unused_keys()


@pytest.mark.parametrize("getter,key,message", [
    ("get_int", "topic.Vision", r"app.properties: topic.Vision = 'VisionTopic' is not an integer"),
    ("get_float", "topic.Vision", r"app.properties: topic.Vision = 'VisionTopic' is not a number"),
    ("get_bool", "topic.Vision", r"app.properties: topic.Vision = 'VisionTopic' is not a boolean"),
    ("get_str", "config.absent", r"app.properties: missing required key 'config.absent'"),
    ("get_int", "config.absent", r"app.properties: missing required key 'config.absent'"),
])
def test_malformed_values_name_file_key_and_expectation(props: Properties, getter: str, key: str,
                                                        message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        getattr(props, getter)(key)


def test_out_of_range(props: Properties) -> None:
    with pytest.raises(ConfigError, match=r"config.domainId = 7 is out of range \(expected 0..5\)"):
        props.get_int("config.domainId", minimum=0, maximum=5)


def test_choice(props: Properties) -> None:
    with pytest.raises(ConfigError, match=r"topic.Vision = 'VisionTopic' is not one of periodic, event"):
        props.get_choice("topic.Vision", ["periodic", "event"])


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"nothing.properties: properties file not found"):
        Properties.load(tmp_path / "nothing.properties")


def test_line_without_key(tmp_path: Path) -> None:
    path = tmp_path / "bad.properties"
    path.write_text("ok=1\n= value\n")
    with pytest.raises(ConfigError, match=r"bad.properties:2: a line has a value but no key"):
        Properties.load(path)


def test_unicode_escapes_and_continuation_lines(tmp_path: Path) -> None:
    path = tmp_path / "u.properties"
    path.write_text("config.name = Stra\\u00dfe \\u2192 \\\n    A9\nnext=1\n")
    props = Properties.load(path)
    assert props.get_str("config.name") == "Straße → A9"
    assert props.get_int("next") == 1


def test_bad_unicode_escape_names_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.properties"
    path.write_text("ok=1\n# comment\nname=\\u12G4\n")
    with pytest.raises(ConfigError, match=r"bad.properties:3: invalid \\u escape"):
        Properties.load(path)


# -- declared keys: refused up front, nearest suggested, undeclared reads noted ------------------------------------
SAMPLE_KEYS = PropertyKeys.of("config.domainId", "config.pubInterval", "config.sensorId", "qos.Profile", "dataFile",
                              "long.value", "escaped:key", "config.ratio", "config.enabled", "config.peers",
                              roles=["Vision"], families=["config.filter."])


def test_a_declaration_covers_keys_roles_and_families() -> None:
    assert SAMPLE_KEYS.covers("topic.Vision") and SAMPLE_KEYS.covers("qos.Vision.Profile")
    assert SAMPLE_KEYS.covers("config.filter.Circle")
    assert not SAMPLE_KEYS.covers("config.filter.") and not SAMPLE_KEYS.covers("topic.Lidar")
    assert (SAMPLE_KEYS | PropertyKeys.of(roles=["Lidar"])).covers("topic.Lidar")
    assert SAMPLE_KEYS.nearest("config.pubIntervall") == "config.pubInterval"
    assert SAMPLE_KEYS.nearest("config.sensorid") == "config.sensorId"  # another case
    assert SAMPLE_KEYS.nearest("config.fliter.Circle") == "config.filter.Circle"
    assert SAMPLE_KEYS.nearest("completely.different") is None
    assert SAMPLE_KEYS.nearest("config.Circle") is None  # not shaped as config.filter.<Topic>


def test_the_declared_keys_of_a_file_pass(props: Properties) -> None:
    props.declare(SAMPLE_KEYS, "vision")
    assert props.declared == SAMPLE_KEYS


def test_unknown_keys_are_refused_in_one_line_with_where_and_the_nearest(props: Properties) -> None:
    props.override(["config.pubIntervall=5", "config.nope=1"])
    with pytest.raises(ConfigError) as refused:
        props.declare(SAMPLE_KEYS, "vision")
    message = str(refused.value)
    assert "\n" not in message
    assert message.endswith("app.properties: unknown key(s) for vision: 'config.pubIntervall' (-D; did you mean "
                            "'config.pubInterval'?), 'config.nope' (-D)"), message
    assert props.declared is None


def test_a_file_key_is_named_with_its_file(tmp_path: Path) -> None:
    path = tmp_path / "typo.properties"
    path.write_text("config.domainId=1\nconfig.sensorID=2\n")
    with pytest.raises(ConfigError, match=r"typo.properties: unknown key\(s\) for vision: 'config.sensorID' \(.*"
                                          r"typo.properties; did you mean 'config.sensorId'\?\)$"):
        Properties.load(path).declare(SAMPLE_KEYS, "vision")


def test_reads_of_undeclared_keys_are_noted(props: Properties) -> None:
    props.declare(SAMPLE_KEYS, "vision")
    props.get_int("config.domainId")
    props.get_str("config.undeclared", "x")
    props.get_bool("config.undeclared", True)
    assert props.undeclared_reads() == ["config.undeclared"]
    assert Properties({}).undeclared_reads() == []  # without a declaration nothing is noted

