#!/usr/bin/env python3
"""Gateway benchmarks: messages/s and added latency through ``hwbridge ros2`` and ``hwbridge ros1``.

Processes as in real use. For each gateway:

- the *graph side*: this process owns a graph (a Zenoh router, what a bridge runs) and publishes
  ``sensor_msgs/Imu`` on ``/bench/imuK`` with the wall-clock time in ``header.stamp``;
- the *gateway*: ``hwbridge ros2`` (rclpy) or ``hwbridge ros1`` (with a ``roscore``);
- the *subscriber*: a plain rclpy (rospy) node in its own process that counts what arrives and
  takes ``now - header.stamp`` as each message's latency.

The peer is the same subscriber fed by a plain rclpy (rospy) publisher process: the same traffic
between two plain ROS nodes, measured in the same run. Cases:

- ``robot_50hz_x10``: 10 topics at 50 Hz for a few seconds, a busy small robot. Lines carry the
  delivered fraction and latency p50/p99 of both paths; ``added_p50_ms`` is the gateway's p50
  minus the peer's.
- ``flood``: one topic published as fast as the publisher can for a few seconds;
  ``hwbridge_per_s`` is what the subscriber received per second through the gateway (counted
  until half a second after the publishing time), and ``headroom`` that rate over the 500
  messages/s of the robot case. The rate is that of the slowest stage: for the peer it is
  often the plain client library's publisher (rospy publishes far slower than it receives), so
  the flood's ratio says which path moves more, not that a gateway beats a direct connection.
  Latencies in a flood are queueing time.

Prints one JSON object per line. ``--only ros2|ros1`` runs one gateway. The ROS 2 part needs
the ``[ros2]`` wheels, the ROS 1 part ``roscore`` and python3-rospy (Debian); a part whose ROS
is missing prints a ``skipped`` line.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve()
ROOT = HERE.parents[2]
ROBOT_TOPICS, ROBOT_RATE = 10, 50.0


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _summary(latencies: list[float], seconds: float) -> dict[str, Any]:
    ordered = sorted(latencies)
    return {
        "count": len(ordered),
        "per_s": len(ordered) / seconds,
        "p50_ms": statistics.median(ordered) * 1e3 if ordered else None,
        "p99_ms": ordered[int(len(ordered) * 0.99)] * 1e3 if ordered else None,
    }


# ---------------------------------------------------------------------- roles (child processes)
def _ros2_modules() -> tuple[Any, Any, Any]:
    """rclpy, rclpy.qos and sensor_msgs/msg/Imu (imported by name: they are optional)."""
    return (
        importlib.import_module("rclpy"),
        importlib.import_module("rclpy.qos"),
        importlib.import_module("sensor_msgs.msg").Imu,
    )


def role_ros2_sub(topics: int, seconds: float, match: bool) -> None:
    rclpy, qos_mod, Imu = _ros2_modules()
    QoSProfile, ReliabilityPolicy = qos_mod.QoSProfile, qos_mod.ReliabilityPolicy

    rclpy.init()
    node = rclpy.create_node(f"bench_sub_{os.getpid()}")
    latencies: list[float] = []
    first: list[float] = []

    def take(message: Any) -> None:
        now = time.time()
        if not first:
            first.append(now)
        stamp = message.header.stamp
        latencies.append(now - (stamp.sec + stamp.nanosec * 1e-9))

    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    subscriptions = [
        node.create_subscription(Imu, f"/bench/imu{index}", take, qos) for index in range(topics)
    ]
    wait = time.monotonic() + (30 if match else 0)
    while time.monotonic() < wait and not all(s.get_publisher_count() for s in subscriptions):
        rclpy.spin_once(node, timeout_sec=0.05)  # matched with every publisher: then measure
    print("ready", flush=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
        if first and time.time() - first[0] > seconds + 0.5:
            break
    print(json.dumps(_summary(latencies, seconds)), flush=True)
    node.destroy_node()
    rclpy.shutdown()


def role_ros2_pub(topics: int, rate: float, seconds: float) -> None:
    rclpy, qos_mod, Imu = _ros2_modules()
    QoSProfile, ReliabilityPolicy = qos_mod.QoSProfile, qos_mod.ReliabilityPolicy

    rclpy.init()
    node = rclpy.create_node(f"bench_pub_{os.getpid()}")
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    publishers = [node.create_publisher(Imu, f"/bench/imu{i}", qos) for i in range(topics)]
    wait = time.monotonic() + 30
    while time.monotonic() < wait and not all(p.get_subscription_count() for p in publishers):
        time.sleep(0.05)  # matched with the subscriber: then publish
    time.sleep(0.5)
    message = Imu()
    message.header.frame_id = "imu"
    end = time.monotonic() + seconds
    period = 1.0 / rate if rate else 0.0
    tick = time.monotonic()
    while time.monotonic() < end:
        for publisher in publishers:
            now = time.time()
            message.header.stamp.sec = int(now)
            message.header.stamp.nanosec = int((now % 1) * 1e9)
            publisher.publish(message)
        if period:
            tick += period
            time.sleep(max(0.0, tick - time.monotonic()))
    time.sleep(0.5)
    node.destroy_node()
    rclpy.shutdown()


def role_ros1_sub(topics: int, seconds: float, match: bool) -> None:
    rospy = importlib.import_module("rospy")
    Imu = importlib.import_module("sensor_msgs.msg").Imu

    rospy.init_node(f"bench_sub_{os.getpid()}", disable_signals=True)
    latencies: list[float] = []
    first: list[float] = []

    def take(message: Any) -> None:
        now = time.time()
        if not first:
            first.append(now)
        latencies.append(now - message.header.stamp.to_sec())

    subscribers = [
        rospy.Subscriber(f"/bench/imu{index}", Imu, take, queue_size=1000, tcp_nodelay=True)
        for index in range(topics)
    ]
    wait = time.monotonic() + (30 if match else 0)
    while time.monotonic() < wait and not all(s.get_num_connections() for s in subscribers):
        time.sleep(0.05)
    print("ready", flush=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        time.sleep(0.05)
        if first and time.time() - first[0] > seconds + 0.5:
            break
    print(json.dumps(_summary(list(latencies), seconds)), flush=True)
    rospy.signal_shutdown("done")


def role_ros1_pub(topics: int, rate: float, seconds: float) -> None:
    rospy = importlib.import_module("rospy")
    Imu = importlib.import_module("sensor_msgs.msg").Imu

    rospy.init_node(f"bench_pub_{os.getpid()}", disable_signals=True)
    publishers = [
        rospy.Publisher(f"/bench/imu{i}", Imu, queue_size=1000, tcp_nodelay=True)
        for i in range(topics)
    ]
    wait = time.monotonic() + 30
    while time.monotonic() < wait and not all(p.get_num_connections() for p in publishers):
        time.sleep(0.05)
    time.sleep(0.5)
    message = Imu()
    message.header.frame_id = "imu"
    end = time.monotonic() + seconds
    period = 1.0 / rate if rate else 0.0
    tick = time.monotonic()
    while time.monotonic() < end:
        for publisher in publishers:
            message.header.stamp = rospy.Time.from_sec(time.time())
            publisher.publish(message)
        if period:
            tick += period
            time.sleep(max(0.0, tick - time.monotonic()))
    time.sleep(0.5)
    rospy.signal_shutdown("done")


# ---------------------------------------------------------------------- the run
class Run:
    def __init__(self, kind: str, env: dict[str, str], python: str) -> None:
        self.kind = kind
        self.env = env
        self.python = python
        self.children: list[subprocess.Popen[str]] = []

    def child(self, argv: list[str], python: str | None = None) -> subprocess.Popen[str]:
        process = subprocess.Popen(
            [python or self.python, str(HERE), *argv],
            env=self.env,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            stdin=subprocess.DEVNULL,
            text=True,
        )
        self.children.append(process)
        return process

    def subscriber(self, topics: int, seconds: float, match: bool) -> subprocess.Popen[str]:
        argv = ["--role", f"{self.kind}-sub", "--topics", str(topics), "--seconds", str(seconds)]
        sub = self.child([*argv, "--match"] if match else argv)
        assert sub.stdout is not None
        line = sub.stdout.readline().strip()
        if line != "ready":
            raise RuntimeError(f"{self.kind} subscriber did not start")
        return sub

    @staticmethod
    def result(sub: subprocess.Popen[str]) -> dict[str, Any]:
        assert sub.stdout is not None
        out, _ = sub.communicate(timeout=90)
        return dict(json.loads((out or "").strip().splitlines()[-1]))

    def stop(self) -> None:
        for process in reversed(self.children):
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        for process in self.children:
            try:
                process.wait(10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(5)


def _graph_publish(publishers: list[Any], template: bytes, rate: float, seconds: float) -> None:
    import struct

    data = bytearray(template)
    end = time.monotonic() + seconds
    period = 1.0 / rate if rate else 0.0
    tick = time.monotonic()
    while time.monotonic() < end:
        for publisher in publishers:
            now = time.time()
            struct.pack_into("<II", data, 4, int(now), int((now % 1) * 1e9))  # after seq
            publisher.publish_raw(bytes(data))
        if period:
            tick += period
            time.sleep(max(0.0, tick - time.monotonic()))


def bench_gateway(kind: str, seconds: float) -> None:
    from hwbridge import msg
    from hwbridge.graph import Graph

    port = _free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    env = {**os.environ, "HWBRIDGE_ENDPOINT": endpoint, "HWBRIDGE_DOMAIN": "bench"}
    python = sys.executable
    roscore = None
    if kind == "ros2":
        from hwbridge.gateway.ros2 import ros2_environment

        env = ros2_environment(env=env)
        env["ROS_DOMAIN_ID"] = str(10 + os.getpid() % 90)
        env["_ROS_WHEELS_BOOTSTRAP_COMPLETE"] = "1"
        peer = "rclpy->rclpy"
    else:
        master = f"http://127.0.0.1:{_free_port()}"
        env["ROS_MASTER_URI"] = master
        env["ROS_HOME"] = str(
            Path(os.environ.get("TMPDIR", "/tmp")) / f"hwbridge-bench-{os.getpid()}"
        )
        python = "/usr/bin/python3"
        peer = "rospy->rospy"
        roscore = subprocess.Popen(
            ["roscore", "-p", master.rsplit(":", 1)[1]],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        time.sleep(4)
    run = Run(kind, env, python)
    graph = Graph.embedded(listen=[endpoint], domain="bench")
    try:
        node = graph.node("bench_board")
        publishers = [
            node.publisher(f"/bench/imu{i}", "sensor_msgs/Imu") for i in range(ROBOT_TOPICS)
        ]
        template = msg.encode(msg.from_dict("sensor_msgs/Imu", {"header": {"frame_id": "imu"}}))
        gateway_argv = [sys.executable, "-m", "hwbridge", kind, "--topic", "/bench/*"]
        if kind == "ros2":
            gateway_argv += ["--qos", "/bench/*=reliable", "--no-rosout"]
        gateway = subprocess.Popen(
            gateway_argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
        )
        run.children.append(gateway)
        assert gateway.stderr is not None
        deadline = time.monotonic() + 60
        mirrored = 0
        while mirrored < ROBOT_TOPICS and time.monotonic() < deadline:
            line = gateway.stderr.readline()
            if not line:
                raise RuntimeError(f"the {kind} gateway stopped")
            mirrored += "/bench/imu" in line and "graph -> ROS" in line
        cases = [
            ("robot_50hz_x10", ROBOT_TOPICS, ROBOT_RATE),
            ("flood", 1, 0.0),
        ]
        results: dict[str, dict[str, Any]] = {}
        for case, topics, rate in cases:
            sub = run.subscriber(topics, seconds, match=True)  # matched with the gateway
            time.sleep(0.5)
            _graph_publish(publishers[:topics], template, rate, seconds)
            ours = run.result(sub)
            sub = run.subscriber(topics, seconds, match=False)  # the publisher waits for it
            pub = run.child(
                [
                    "--role",
                    f"{kind}-pub",
                    "--topics",
                    str(topics),
                    "--rate",
                    str(rate),
                    "--seconds",
                    str(seconds),
                ]
            )
            theirs = run.result(sub)
            pub.wait(30)
            results[case] = ours
            sent = topics * rate * seconds if rate else None
            extra: dict[str, Any] = {
                "seconds": seconds,
                "hwbridge_p50_ms": _round(ours["p50_ms"]),
                "hwbridge_p99_ms": _round(ours["p99_ms"]),
                "peer_p50_ms": _round(theirs["p50_ms"]),
                "peer_p99_ms": _round(theirs["p99_ms"]),
            }
            if ours["p50_ms"] is not None and theirs["p50_ms"] is not None:
                extra["added_p50_ms"] = _round(ours["p50_ms"] - theirs["p50_ms"])
            if sent:
                extra["hwbridge_delivered"] = round(ours["count"] / sent, 3)
                extra["peer_delivered"] = round(theirs["count"] / sent, 3)
            else:
                extra["headroom"] = round(ours["per_s"] / (ROBOT_TOPICS * ROBOT_RATE), 1)
            _emit(f"gateway_{kind}", case, ours["per_s"], peer, theirs["per_s"], extra)
    finally:
        run.stop()
        graph.close()
        if roscore is not None:
            roscore.send_signal(signal.SIGINT)
            roscore.wait(20)


def _round(value: float | None) -> float | None:
    return None if value is None else round(value, 3)


def _emit(
    bench: str, case: str, ours: float, peer: str, theirs: float, extra: dict[str, Any]
) -> None:
    sys.path.insert(0, str(HERE.parent))
    from _common import emit

    emit(bench, {"case": case}, ours, peer, theirs, **extra)


def main() -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--only", choices=["ros2", "ros1"])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--role")
    parser.add_argument("--topics", type=int, default=1)
    parser.add_argument("--rate", type=float, default=0.0)
    parser.add_argument("--match", action="store_true")
    args = parser.parse_args()
    roles = {
        "ros2-sub": lambda: role_ros2_sub(args.topics, args.seconds, args.match),
        "ros2-pub": lambda: role_ros2_pub(args.topics, args.rate, args.seconds),
        "ros1-sub": lambda: role_ros1_sub(args.topics, args.seconds, args.match),
        "ros1-pub": lambda: role_ros1_pub(args.topics, args.rate, args.seconds),
    }
    if args.role:
        roles[args.role]()
        return 0
    sys.path.insert(0, str(ROOT))
    for kind in ("ros2", "ros1"):
        if args.only not in (None, kind):
            continue
        missing = _missing(kind)
        if missing:
            print(json.dumps({"bench": f"gateway_{kind}", "skipped": missing}), flush=True)
            continue
        bench_gateway(kind, args.seconds)
    return 0


def _missing(kind: str) -> str | None:
    if kind == "ros1":
        if shutil.which("roscore") is None or not Path("/usr/bin/python3").exists():
            return "roscore (Debian ros-core, python3-rospy) is not installed"
        return None
    from hwbridge.gateway.ros2 import ros2_environment

    done = subprocess.run(
        [sys.executable, "-c", "import rclpy, sensor_msgs.msg"],
        env=ros2_environment(),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    if done.returncode != 0:
        return f"rclpy is not installed (pip install 'hwbridge[ros2]'): {done.stderr[-200:]}"
    return None


if __name__ == "__main__":
    sys.exit(main())
