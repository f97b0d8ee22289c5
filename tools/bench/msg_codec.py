#!/usr/bin/env python3
"""Encode/decode rates of hwbridge.msg for a few common types, against rosbags called directly.

The peer is the rosbags type store that hwbridge.msg wraps, so ``ratio`` shows what hwbridge's
layer costs (names, checks, error wrapping). Runs in well under two minutes with no arguments.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import emit, rate

from hwbridge import msg

N = 2000
SAMPLES = {
    "std_msgs/String": {"data": "hello world!"},
    "sensor_msgs/Imu": {
        "header": {"seq": 1, "stamp": 1.5, "frame_id": "imu_link"},
        "orientation": {"w": 1.0},
        "orientation_covariance": [-1.0] + [0.0] * 8,
        "linear_acceleration": {"z": 9.81},
    },
    "nav_msgs/Odometry": {
        "header": {"seq": 1, "stamp": 1.5, "frame_id": "odom"},
        "child_frame_id": "base_link",
        "pose": {"pose": {"position": {"x": 1.0}, "orientation": {"w": 1.0}}},
        "twist": {"twist": {"linear": {"x": 0.3}}},
    },
}


def main() -> None:
    reg = msg.registry()
    store = reg._store  # the peer: rosbags itself, without hwbridge's layer
    for type_name, data in SAMPLES.items():
        message = msg.from_dict(type_name, data)
        wire = msg.encode(message)
        store_name = reg.message(type_name).store_name

        def ours_encode(m: object = message, t: str = type_name) -> None:
            for _ in range(N):
                msg.encode(m, t)

        def peer_encode(m: object = message, s: str = store_name) -> None:
            for _ in range(N):
                store.serialize_ros1(m, s)

        def ours_decode(w: bytes = wire, t: str = type_name) -> None:
            for _ in range(N):
                msg.decode(w, t)

        def peer_decode(w: bytes = wire, s: str = store_name) -> None:
            for _ in range(N):
                store.deserialize_ros1(w, s)

        case = {"type": type_name, "bytes": len(wire)}
        emit("msg_encode", case, rate(ours_encode, N), "rosbags", rate(peer_encode, N))
        emit("msg_decode", case, rate(ours_decode, N), "rosbags", rate(peer_decode, N))


if __name__ == "__main__":
    main()
