"""The gateways' pure parts: type names, layouts, byte conversion, selection, QoS, TCPROS headers.

No ROS needed: CDR bytes are checked against rosbags' own ROS 2 serializer.
"""

from __future__ import annotations

import socket
import threading
from typing import Any

import pytest
from rosbags.typesys import Stores, get_typestore

from hwbridge import msg
from hwbridge.gateway.common import Selection
from hwbridge.gateway.ros2 import qos_kind, ros2_environment
from hwbridge.gateway.tcpros import encode_header, parse_header, read_frame, read_header
from hwbridge.gateway.types import (
    CdrConverter,
    TypeMapError,
    ros1_type_name,
    ros2_type_name,
)


def test_type_names_map_both_ways() -> None:
    assert ros2_type_name("std_msgs/String") == "std_msgs/msg/String"
    assert ros2_type_name("std_srvs/Trigger", "srv") == "std_srvs/srv/Trigger"
    assert ros2_type_name("tf/tfMessage") == "tf2_msgs/msg/TFMessage"
    assert ros1_type_name("std_msgs/msg/String") == "std_msgs/String"
    assert ros1_type_name("std_srvs/srv/Trigger") == "std_srvs/Trigger"
    for bad in ("String", "a/b/c", "/x"):
        with pytest.raises(TypeMapError):
            ros2_type_name(bad)
    with pytest.raises(TypeMapError):
        ros1_type_name("std_msgs/String")


@pytest.fixture(scope="module")
def converter() -> CdrConverter:
    return CdrConverter(msg.registry())


def test_imu_becomes_the_cdr_ros2_would_write_and_comes_back(converter: CdrConverter) -> None:
    imu = msg.from_dict(
        "sensor_msgs/Imu",
        {
            "header": {"seq": 41, "stamp": {"secs": 1700000000, "nsecs": 5}, "frame_id": "imu"},
            "linear_acceleration": {"z": 9.81},
            "orientation_covariance": [float(i) for i in range(9)],
        },
    )
    converter.prepare("sensor_msgs/msg/Imu", "sensor_msgs/msg/Imu")
    cdr = converter.to_cdr(msg.encode(imu), "sensor_msgs/msg/Imu")
    ros2 = get_typestore(Stores.LATEST)
    decoded: Any = ros2.deserialize_cdr(cdr, "sensor_msgs/msg/Imu")
    assert decoded.header.frame_id == "imu"
    assert (decoded.header.stamp.sec, decoded.header.stamp.nanosec) == (1700000000, 5)
    assert decoded.linear_acceleration.z == 9.81
    assert list(decoded.orientation_covariance) == [float(i) for i in range(9)]
    assert bytes(ros2.serialize_cdr(decoded, "sensor_msgs/msg/Imu")) == cdr
    back = msg.to_dict(
        msg.decode(converter.from_cdr(cdr, "sensor_msgs/msg/Imu"), "sensor_msgs/Imu")
    )
    expected = msg.to_dict(imu)
    expected["header"]["seq"] = 0  # ROS 2 has no seq
    assert back == expected


def test_service_halves_and_types_of_our_own_are_described_from_the_registry(
    converter: CdrConverter,
) -> None:
    converter.prepare("std_srvs/msg/TriggerResponse", "std_srvs/srv/Trigger_Response")
    data = msg.encode(msg.new("std_srvs/TriggerResponse", success=True, message="ok"))
    cdr = converter.to_cdr(data, "std_srvs/srv/Trigger_Response")
    assert converter.from_cdr(cdr, "std_srvs/srv/Trigger_Response") == data
    # hwbridge_msgs exist only here: taken with their ROS 1 layout.
    converter.prepare("hwbridge_msgs/msg/WheelTicks", "hwbridge_msgs/msg/WheelTicks")


@pytest.mark.parametrize("frame_id", ["", "a", "ab", "abc", "sonar"])
def test_fields_ros2_added_at_the_end_go_as_zeros_and_come_back_dropped(
    converter: CdrConverter, frame_id: str
) -> None:
    fields = {
        "header": {"stamp": {"secs": 7, "nsecs": 9}, "frame_id": frame_id},
        "radiation_type": 1,
        "field_of_view": 0.25,
        "min_range": 0.02,
        "max_range": 4.0,
        "range": 1.5,
    }
    data = msg.encode(msg.from_dict("sensor_msgs/Range", fields))
    converter.prepare("sensor_msgs/msg/Range", "sensor_msgs/msg/Range")
    assert converter.added_fields("sensor_msgs/msg/Range") == ["variance"]
    ros2 = get_typestore(Stores.LATEST)
    decoded: Any = ros2.deserialize_cdr(
        converter.to_cdr(data, "sensor_msgs/msg/Range"), "sensor_msgs/msg/Range"
    )
    assert (decoded.header.frame_id, decoded.range, decoded.variance) == (frame_id, 1.5, 0.0)
    decoded.variance = 0.125
    cdr = bytes(ros2.serialize_cdr(decoded, "sensor_msgs/msg/Range"))
    assert converter.from_cdr(cdr, "sensor_msgs/msg/Range") == data


def test_a_layout_that_differs_is_refused_with_the_fields(converter: CdrConverter) -> None:
    with pytest.raises(TypeMapError, match="stamp"):
        converter.prepare("rosgraph_msgs/msg/Log", "rcl_interfaces/msg/Log")


def test_selection_patterns_and_exclusions() -> None:
    chosen = Selection.of(["/diffbot/*", "/tf"], ["*/imu_raw"])
    assert chosen("/diffbot/odom")
    assert chosen("/diffbot/pan/goal_position")
    assert chosen("/tf")
    assert not chosen("/diffbot/imu_raw")
    assert not chosen("/other/odom")
    assert Selection.of(None, None)("/anything")
    assert not Selection(())("/anything")


def test_qos_reaches_default_and_sensor_subscribers() -> None:
    # Published reliable (default and sensor-data subscribers match), subscribed best effort
    # (reliable and best-effort publishers match); see tests/gateway/test_ros2_qos.py.
    assert qos_kind("/diffbot/imu", "to_ros").name == "reliable"
    assert qos_kind("/diffbot/odom", "to_ros").name == "reliable"
    assert qos_kind("/diffbot/cmd_vel", "from_ros").name == "sensor"
    assert qos_kind("/tf", "to_ros").name == "tf"
    assert qos_kind("/tf_static", "to_ros").name == "latched"
    assert qos_kind("/rosout", "to_ros").name == "rosout"
    assert qos_kind("/chatter", "to_ros").name == "reliable"


def test_the_ros2_environment_adds_its_paths_after_existing_ones() -> None:
    env = ros2_environment(
        "/opt/venv", {"LD_LIBRARY_PATH": "/usr/lib/x", "RMW_IMPLEMENTATION": "r"}
    )
    assert env["LD_LIBRARY_PATH"].split(":") == ["/usr/lib/x", "/opt/venv/lib"]
    assert env["AMENT_PREFIX_PATH"] == "/opt/venv"
    assert env["RMW_IMPLEMENTATION"] == "r"
    again = ros2_environment("/opt/venv", env)
    assert again["LD_LIBRARY_PATH"] == env["LD_LIBRARY_PATH"]


def test_tcpros_headers_round_trip_over_a_socket() -> None:
    fields = {"callerid": "/x", "topic": "/t", "md5sum": "*", "message_definition": "a=b\nc"}
    assert parse_header(encode_header(fields)[4:]) == fields
    left, right = socket.socketpair()
    with left, right:
        sender = threading.Thread(
            target=lambda: left.sendall(encode_header(fields) + b"\x03\x00\x00\x00abc")
        )
        sender.start()
        assert read_header(right) == fields
        assert read_frame(right) == b"abc"
        sender.join()
