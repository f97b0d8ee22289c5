"""A plain rclpy node for the gateway tests, run as its own process (``python ros2_peer.py CMD``).

Commands (each prints JSON lines on stdout and exits 0 when done, 1 on a timeout):

- ``echo TOPIC TYPE N [QOS]``: the first N messages (``sensor_msgs/msg/Imu``), as dicts;
- ``receive QOS TOPIC=TYPE...``: subscribe to every TOPIC, wait until each has delivered a
  message; prints ``{"received": {TOPIC: COUNT}, "missing": [TOPIC...]}``;
- ``pub TOPIC TYPE JSON RATE SECONDS [QOS]``: publish a message (fields as JSON) at RATE Hz;
- ``call SERVICE TYPE JSON``: call a service once, print the response;
- ``rosout TEXT``: wait for a /rosout entry containing TEXT, print it;
- ``serve SERVICE SECONDS``: serve std_srvs/srv/Trigger (message ``ros2 says hi``);
- ``qos TOPIC...``: the reliability and durability of the gateway's endpoints on each TOPIC;
- ``tf TOPIC PARENT CHILD [static]``: the first PARENT -> CHILD transform on TOPIC (a
  ``tf2_msgs/msg/TFMessage``; ``static``: subscribed transient local, as tf2_ros' static
  listener does) and the type hashes its publishers offer.

QOS is ``default``, what most nodes write (``create_subscription(T, topic, cb, 10)``: reliable,
volatile, keep last 10), or ``sensor`` (``qos_profile_sensor_data``: best effort); ``echo``
defaults to ``sensor``, ``pub`` to ``default``.
"""

from __future__ import annotations

import importlib
import json
import sys
import time
from typing import Any

TIMEOUT = 20.0


def _class(name: str) -> Any:
    package, kind, base = name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), base)


def _to_dict(message: Any) -> Any:
    if hasattr(message, "get_fields_and_field_types"):
        return {
            name: _to_dict(getattr(message, name)) for name in message.get_fields_and_field_types()
        }
    if hasattr(message, "tolist"):
        return message.tolist()
    if isinstance(message, (list, tuple)):
        return [_to_dict(item) for item in message]
    return message


def _fill(message: Any, values: dict[str, Any]) -> Any:
    for name, value in values.items():
        if isinstance(value, dict):
            _fill(getattr(message, name), value)
        else:
            setattr(message, name, value)
    return message


def _profile(qos: Any, name: str) -> Any:
    """A subscription's or publisher's QoS as the node code of most ROS 2 packages says it."""
    if name == "default":
        return 10  # rclpy: keep last 10, reliable, volatile
    if name == "sensor":
        return qos.qos_profile_sensor_data
    raise SystemExit(f"unknown QoS {name!r}: default or sensor")


def main(argv: list[str]) -> int:
    rclpy = importlib.import_module("rclpy")  # by name: the [ros2] extra is optional
    qos = importlib.import_module("rclpy.qos")

    rclpy.init()
    node = rclpy.create_node(f"gateway_test_peer_{int(time.time() * 1000) % 100000}")
    command, args = argv[0], argv[1:]
    deadline = time.monotonic() + TIMEOUT
    try:
        if command == "echo":
            topic, type_name, count = args[0], args[1], int(args[2])
            profile = _profile(qos, args[3] if len(args) > 3 else "sensor")
            got: list[Any] = []
            node.create_subscription(_class(type_name), topic, got.append, profile)
            while len(got) < count and time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.1)
            for message in got[:count]:
                print(json.dumps(_to_dict(message)), flush=True)
            return 0 if len(got) >= count else 1
        if command == "receive":
            profile = _profile(qos, args[0])
            counts: dict[str, int] = {}

            def counter(topic: str) -> Any:
                def count(_message: Any) -> None:
                    counts[topic] += 1

                return count

            for pair in args[1:]:
                topic, _, type_name = pair.partition("=")
                counts[topic] = 0
                node.create_subscription(_class(type_name), topic, counter(topic), profile)
            deadline = time.monotonic() + 3 * TIMEOUT
            while not all(counts.values()) and time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.1)
            missing = sorted(topic for topic, n in counts.items() if not n)
            print(json.dumps({"received": counts, "missing": missing}), flush=True)
            return 0 if not missing else 1
        if command == "pub":
            topic, type_name, fields, rate, seconds = args[:5]
            cls = _class(type_name)
            publisher = node.create_publisher(
                cls, topic, _profile(qos, args[5] if len(args) > 5 else "default")
            )
            end = time.monotonic() + float(seconds)
            while time.monotonic() < end:
                publisher.publish(_fill(cls(), json.loads(fields)))
                rclpy.spin_once(node, timeout_sec=1.0 / float(rate))
            return 0
        if command == "call":
            name, type_name, fields = args
            cls = _class(type_name)
            client = node.create_client(cls, name)
            if not client.wait_for_service(timeout_sec=TIMEOUT):
                return 1
            future = client.call_async(_fill(cls.Request(), json.loads(fields)))
            rclpy.spin_until_future_complete(node, future, timeout_sec=TIMEOUT)
            if not future.done():
                return 1
            print(json.dumps(_to_dict(future.result())), flush=True)
            return 0
        if command == "rosout":
            text = args[0]
            log_cls = _class("rcl_interfaces/msg/Log")
            found: list[Any] = []
            profile = qos.QoSProfile(
                depth=1000,
                reliability=qos.ReliabilityPolicy.RELIABLE,
                durability=qos.DurabilityPolicy.TRANSIENT_LOCAL,
            )
            node.create_subscription(
                log_cls, "/rosout", lambda m: found.append(m) if text in m.msg else None, profile
            )
            print(json.dumps({"ready": True}), flush=True)
            while not found and time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.1)
            if found:
                print(json.dumps(_to_dict(found[0])), flush=True)
            return 0 if found else 1
        if command == "serve":
            name, seconds = args[0], float(args[1])
            trigger = _class("std_srvs/srv/Trigger")

            def answer(_request: Any, response: Any) -> Any:
                response.success = True
                response.message = "ros2 says hi"
                return response

            node.create_service(trigger, name, answer)
            print(json.dumps({"ready": True}), flush=True)
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.1)
            return 0
        if command == "qos":
            # The QoS of the gateway's endpoints on each topic, as discovery reports them.
            endpoints: dict[str, list[tuple[str, Any]]] = {topic: [] for topic in args}
            while not all(endpoints.values()) and time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.1)
                for topic in args:
                    infos = [
                        ("publisher", info) for info in node.get_publishers_info_by_topic(topic)
                    ] + [
                        ("subscription", info)
                        for info in node.get_subscriptions_info_by_topic(topic)
                    ]
                    endpoints[topic] = [
                        (kind, i) for kind, i in infos if i.node_name.startswith("hwbridge")
                    ]
            for topic, found_here in endpoints.items():
                for kind, info in found_here:
                    profile = info.qos_profile
                    print(
                        json.dumps(
                            {
                                "topic": topic,
                                "kind": kind,
                                "reliability": profile.reliability.name.lower(),
                                "durability": profile.durability.name.lower(),
                            }
                        ),
                        flush=True,
                    )
            return 0 if all(endpoints.values()) else 1
        if command == "tf":
            topic, parent, child = args[:3]
            latched = args[3:4] == ["static"]
            durability = qos.DurabilityPolicy
            profile = qos.QoSProfile(
                depth=100,
                reliability=qos.ReliabilityPolicy.RELIABLE,
                durability=durability.TRANSIENT_LOCAL if latched else durability.VOLATILE,
            )
            transforms: list[Any] = []

            def keep(message: Any) -> None:
                transforms.extend(
                    t
                    for t in message.transforms
                    if t.header.frame_id == parent and t.child_frame_id == child
                )

            node.create_subscription(_class("tf2_msgs/msg/TFMessage"), topic, keep, profile)
            print(json.dumps({"ready": True}), flush=True)
            while not transforms and time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.1)
            if not transforms:
                return 1
            hashes = sorted(
                str(info.topic_type_hash) for info in node.get_publishers_info_by_topic(topic)
            )
            print(
                json.dumps({"transform": _to_dict(transforms[0]), "type_hashes": hashes}),
                flush=True,
            )
            return 0
        print(f"unknown command {command}", file=sys.stderr)
        return 2
    finally:
        node.destroy_node()
        rclpy.shutdown()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
