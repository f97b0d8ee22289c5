"""hwbridge.msg: md5 sums, ROS 1 bytes, dict/YAML conversion and malformed definitions."""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hwbridge import msg
from hwbridge.errors import (
    DefinitionError,
    HwBridgeError,
    MessageTypeError,
    SerializationError,
    UnknownTypeError,
)
from hwbridge.protocols.msgtypes import BUNDLED_MSG_DIR, TypeRegistry
from tests.strategies import message_dicts, messages

VECTORS = json.loads((BUNDLED_MSG_DIR.parent / "vectors" / "md5.json").read_text())
SPEC = Path(__file__).resolve().parents[3] / "shared" / "specs" / "MESSAGES.md"
REG = msg.registry()


@pytest.mark.parametrize("vector", VECTORS["messages"], ids=lambda v: v["type"])
def test_message_md5_vectors(vector: dict[str, str]) -> None:
    assert msg.md5(vector["type"]) == vector["md5"]
    assert REG.message(vector["type"]).md5 == vector["md5"]


@pytest.mark.parametrize("vector", VECTORS["services"], ids=lambda v: v["type"])
def test_service_md5_vectors(vector: dict[str, str]) -> None:
    assert REG.service(vector["type"]).md5 == vector["md5"]


@pytest.mark.skipif(not SPEC.exists(), reason="shared/specs is not beside this checkout")
def test_vectors_cover_the_spec_table() -> None:
    table = dict(re.findall(r"^\| ([a-z_]+/\w+)[^|]*\| ([0-9a-f]{32}) \|$", SPEC.read_text(), re.M))
    ours = {v["type"]: v["md5"] for v in VECTORS["messages"]}
    assert table, "no md5 rows found in MESSAGES.md"
    for name, md5 in table.items():
        assert ours.get(name) == md5, name


@pytest.mark.parametrize("name", REG.message_names())
def test_md5_agrees_with_rosbags_generator(name: str) -> None:
    """Our hash text (needed for service md5s) matches rosbags' own md5 for every type."""
    store = REG._store  # the one place a test looks inside: cross-check two implementations
    assert REG.message(name).md5 == store.generate_msgdef(REG.message(name).store_name)[1]


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return bool(a == b) and type(a) is type(b)


@pytest.mark.parametrize("name", REG.message_names())
@settings(
    max_examples=8,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(data=st.data())
def test_round_trip_every_standard_type(name: str, data: Any) -> None:
    message = data.draw(messages(REG, name))
    wire = msg.encode(message)
    back = msg.decode(wire, name)
    assert _same(msg.to_dict(back), msg.to_dict(message))
    assert msg.encode(back) == wire


@settings(max_examples=50, deadline=None, derandomize=True)
@given(data=message_dicts(REG, "sensor_msgs/JointState"))
def test_dict_round_trip_joint_state(data: dict[str, Any]) -> None:
    message = msg.from_dict("sensor_msgs/JointState", data)
    again = msg.to_dict(message)
    assert _same(again["name"], data["name"])
    assert again["position"] == pytest.approx(data["position"])
    assert msg.to_dict(msg.from_yaml("sensor_msgs/JointState", msg.to_yaml(message))) == again


def test_known_bytes_of_string_and_header() -> None:
    assert msg.encode(msg.new("std_msgs/String", data="hello world!")).hex() == (
        "0c00000068656c6c6f20776f726c6421"
    )
    header = msg.from_dict("std_msgs/Header", {"seq": 7, "stamp": 1.25, "frame_id": "odom"})
    assert msg.encode(header) == bytes.fromhex("070000000100000080b2e60e04000000") + b"odom"


def test_float32_field_is_four_bytes_and_float64_eight() -> None:
    rng = msg.new("sensor_msgs/Range", range=1.5)
    assert len(msg.encode(rng)) == 4 + 8 + 4 + 1 + 4 * 4  # header (empty frame id) + fields
    assert len(msg.encode(msg.new("std_msgs/Float64", data=1.5))) == 8


def test_from_dict_defaults_and_time_forms() -> None:
    twist = msg.from_dict("geometry_msgs/Twist", {"angular": {"z": 1}})
    assert msg.to_dict(twist) == {
        "linear": {"x": 0.0, "y": 0.0, "z": 0.0},
        "angular": {"x": 0.0, "y": 0.0, "z": 1.0},
    }
    for stamp in (3.5, {"secs": 3, "nsecs": 500_000_000}, {"sec": 3, "nanosec": 500_000_000}):
        header = msg.from_dict("std_msgs/Header", {"stamp": stamp})
        assert msg.to_dict(header)["stamp"] == {"secs": 3, "nsecs": 500_000_000}


@pytest.mark.parametrize(
    ("data", "needle"),
    [
        ({"linear": {"x": "fast"}}, "linear.x: expected a number"),
        ({"linaer": {}}, "linaer: no such field in geometry_msgs/Twist"),
        ({"linear": 3}, "linear: expected a mapping for geometry_msgs/Vector3"),
    ],
)
def test_from_dict_errors_name_the_field(data: dict[str, Any], needle: str) -> None:
    with pytest.raises(MessageTypeError, match=re.escape(needle)):
        msg.from_dict("geometry_msgs/Twist", data)


def test_from_dict_checks_ranges_and_fixed_sizes() -> None:
    with pytest.raises(MessageTypeError, match=r"data: 256 is out of range for uint8"):
        msg.from_dict("std_msgs/UInt8", {"data": 256})
    with pytest.raises(MessageTypeError, match=r"expected exactly 9 elements, got 2"):
        msg.from_dict("sensor_msgs/Imu", {"orientation_covariance": [1, 2]})
    with pytest.raises(MessageTypeError, match=r"expected true or false"):
        msg.from_dict("std_msgs/Bool", {"data": "yes"})


def test_decode_rejects_wrong_sizes() -> None:
    with pytest.raises(SerializationError, match="left over"):
        msg.decode(b"\x01\x00\x00\x00ab", "std_msgs/String")
    with pytest.raises(SerializationError):
        msg.decode(b"\x10\x00\x00\x00ab", "std_msgs/String")
    with pytest.raises(SerializationError):
        msg.decode(b"\x00", "std_msgs/Int32")


def test_unknown_type_names_closest() -> None:
    with pytest.raises(UnknownTypeError) as info:
        msg.md5("sensor_msgs/Imuu")
    assert "sensor_msgs/Imu" in info.value.suggestions
    with pytest.raises(UnknownTypeError) as info:
        REG.message("geometry_msgs/String")
    assert info.value.suggestions[0] == "std_msgs/String"
    assert "did you mean std_msgs/String" in str(info.value)
    with pytest.raises(UnknownTypeError, match="service type"):
        REG.service("std_srvs/Trigerr")


def test_service_halves_are_messages_but_not_listed() -> None:
    service = REG.service("std_srvs/SetBool")
    assert service.request.name == "std_srvs/SetBoolRequest"
    assert msg.encode(msg.new("std_srvs/SetBoolResponse", success=True, message="ok")) == (
        b"\x01\x02\x00\x00\x00ok"
    )
    assert "std_srvs/SetBoolRequest" not in REG.message_names()
    assert "std_srvs/SetBool" in REG.service_names()


def test_show_nests_like_rosmsg() -> None:
    text = msg.show("geometry_msgs/PoseStamped")
    assert text.splitlines()[:5] == [
        "std_msgs/Header header",
        "  uint32 seq",
        "  time stamp",
        "  string frame_id",
        "geometry_msgs/Pose pose",
    ]
    assert msg.show("sensor_msgs/Range").splitlines()[0] == "uint8 ULTRASOUND=0"


# ---------------------------------------------------------------- user packages and errors
def _package(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def test_user_package_on_search_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _package(
        tmp_path,
        {
            "robot_msgs/msg/WheelTicks.msg": "# encoder counts\nHeader header\nint32 left\n"
            "int32 right  # trailing comment\nuint8 MODE_X4=4\n",
            "robot_msgs/msg/Wheels.msg": "WheelTicks[2] pairs\ngeometry_msgs/Twist cmd\n",
            "robot_msgs/srv/Calibrate.srv": "string FOO=a # b\nWheelTicks start\n---\nbool ok\n",
        },
    )
    reg = TypeRegistry([tmp_path])
    assert reg.message_names("robot_msgs") == ["robot_msgs/WheelTicks", "robot_msgs/Wheels"]
    assert reg.constants("robot_msgs/WheelTicks") == [("MODE_X4", "uint8", 4)]
    assert reg.constants("robot_msgs/CalibrateRequest") == [("FOO", "string", "a # b")]
    ticks = msg.new("robot_msgs/WheelTicks", reg, left=-5, right=7)
    assert msg.decode(msg.encode(ticks, reg=reg), "robot_msgs/WheelTicks", reg).right == 7
    assert len(reg.service("robot_msgs/Calibrate").md5) == 32
    monkeypatch.setenv(msg.ENV_VAR, str(tmp_path))
    assert "robot_msgs/Wheels" in msg.registry().message_names()


def test_a_child_process_gets_the_msg_path_folders_only(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The command warns about an entry that is no folder (once); its children get the folders
    only, so their registries find the same types and warn about nothing."""
    typo = tmp_path / "msgz"
    value = os.pathsep.join([str(typo), str(tmp_path), ""])
    with caplog.at_level("WARNING", logger="hwbridge.msg"):
        env = msg.child_environment({msg.ENV_VAR: value, "OTHER": "kept"})
        assert msg.child_environment({msg.ENV_VAR: value}) == {msg.ENV_VAR: str(tmp_path)}
        assert env == {msg.ENV_VAR: str(tmp_path), "OTHER": "kept"}
        warned = [r.getMessage() for r in caplog.records]
        assert warned == [f"{msg.ENV_VAR} entry {typo} does not exist; skipped"]
        caplog.clear()
        assert msg.child_environment(env) == env  # the child's children alike
    assert caplog.records == []
    assert msg.child_environment({msg.ENV_VAR: str(typo)}) == {msg.ENV_VAR: ""}
    assert msg.child_environment({}) == {}


@pytest.mark.parametrize(
    ("files", "path", "line", "needle"),
    [
        ({"p/msg/A.msg": "int32 x\nflot32 y\n"}, "p/msg/A.msg", 2, "unknown type 'p/flot32'"),
        ({"p/msg/A.msg": "int32 x\nint32[ y\n"}, "p/msg/A.msg", 2, "bad type 'int32['"),
        ({"p/msg/A.msg": "int32 2x\n"}, "p/msg/A.msg", 1, "bad field name '2x'"),
        ({"p/msg/A.msg": "int32\n"}, "p/msg/A.msg", 1, "expected 'TYPE NAME'"),
        ({"p/msg/A.msg": "int32 a b\n"}, "p/msg/A.msg", 1, "extra words"),
        ({"p/msg/A.msg": "uint8 X=300\n"}, "p/msg/A.msg", 1, "out of range for uint8"),
        ({"p/msg/A.msg": "int32 X=abc\n"}, "p/msg/A.msg", 1, "is not an integer"),
        ({"p/msg/A.msg": "float32 X=1.2.3\n"}, "p/msg/A.msg", 1, "is not a float32 value"),
        ({"p/msg/A.msg": "time X=3\n"}, "p/msg/A.msg", 1, "constants must be one of"),
        ({"p/msg/A.msg": "int32 x\nint32 x\n"}, "p/msg/A.msg", 2, "duplicate name 'x'"),
        (
            {"p/msg/A.msg": "int32 x\ngeometry_msgs/Twst t\n"},
            "p/msg/A.msg",
            2,
            "unknown type 'geometry_msgs/Twst'; did you mean geometry_msgs/Twist",
        ),
        ({"p/srv/S.srv": "int32 a\nint32 b\n"}, "p/srv/S.srv", None, "missing '---'"),
        ({"p/srv/S.srv": "int32 a\n---\n---\n"}, "p/srv/S.srv", 3, "a second '---'"),
        (
            {"p/srv/S.srv": "int32 a\n---\nbool ok\nNope n\n"},
            "p/srv/S.srv",
            4,
            "unknown type 'p/Nope'",
        ),
    ],
)
def test_malformed_definitions(
    tmp_path: Path, files: dict[str, str], path: str, line: int | None, needle: str
) -> None:
    _package(tmp_path, files)
    with pytest.raises(DefinitionError) as info:
        TypeRegistry([tmp_path])
    error = info.value
    assert error.path == str(tmp_path / path)
    assert error.line == line
    assert needle in str(error)
    where = f"{tmp_path / path}:{line}" if line else str(tmp_path / path)
    assert str(error).startswith(where + ": ")
    assert isinstance(error, HwBridgeError)


def test_conflicting_redefinition_of_a_standard_type(tmp_path: Path) -> None:
    _package(tmp_path, {"std_msgs/msg/String.msg": "int32 data\n"})
    with pytest.raises(DefinitionError, match="redefines std_msgs/String differently"):
        TypeRegistry([tmp_path])


def test_identical_redefinition_is_accepted(tmp_path: Path) -> None:
    _package(tmp_path, {"std_msgs/msg/String.msg": "string data\n"})
    assert TypeRegistry([tmp_path]).md5("std_msgs/String") == "992ce8a1687cec8c8bd883ec73ca41d1"


def test_time_limits_are_explicit() -> None:
    with pytest.raises(
        MessageTypeError, match=r"stamp: secs must be an integer in \[0, 2147483647\]"
    ):
        msg.from_dict("std_msgs/Header", {"stamp": {"secs": 2**31}})
    with pytest.raises(MessageTypeError, match="nsecs must be an integer"):
        msg.from_dict("std_msgs/Header", {"stamp": {"secs": 1, "nsecs": 10**9}})
    negative = msg.from_dict("std_msgs/Duration", {"data": -1.5})
    assert msg.to_dict(negative) == {"data": {"secs": -2, "nsecs": 500_000_000}}
