"""Protocol auto-detection: native vs rosserial from a board's first bytes."""

from __future__ import annotations

import json
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge.protocols.detect import ProtocolDetector, detect_protocol
from hwbridge.protocols.msgtypes import BUNDLED_MSG_DIR
from hwbridge.protocols.native.framing import Frame, FrameType
from hwbridge.protocols.native.framing import encode_frame as native_frame
from hwbridge.protocols.rosserial.framing import encode_frame as ros_frame

SETTINGS = settings(max_examples=100, deadline=None, derandomize=True)
VECTORS = BUNDLED_MSG_DIR.parent / "vectors"
NATIVE: list[dict[str, Any]] = json.loads((VECTORS / "native_frames.json").read_text())["vectors"]
ROS: list[dict[str, Any]] = json.loads((VECTORS / "rosserial.json").read_text())["frames"]

# a board's first native frame starts with a delimiter, which ends whatever came before it
NATIVE_HELLO = native_frame(Frame(FrameType.RELIABLE, 0, 0, b"\x10hello"), lead=True)
ROS_TIME_REQUEST = ros_frame(10, bytes(8))
ROS_CHATTER = bytes.fromhex("fffe1000ef7d000c00000068656c6c6f20776f726c6421f9")
BOOT_NOISE = bytes.fromhex("f8e0fc00f0f8ff") + b"\x00\xff\xfe\x13"  # bootloader-ish garbage
DEBUG = b"setup() done, free ram 1234\r\n"


@pytest.mark.parametrize("vector", NATIVE, ids=lambda v: v["name"])
def test_every_native_vector(vector: dict[str, Any]) -> None:
    assert detect_protocol(bytes.fromhex(vector["hex"])) == "native"


@pytest.mark.parametrize(
    "vector", [v for v in ROS if v["direction"] == "device_to_host"], ids=lambda v: v["name"]
)
def test_every_rosserial_device_vector(vector: dict[str, Any]) -> None:
    assert detect_protocol(bytes.fromhex(vector["hex"])) == "rosserial"


@pytest.mark.parametrize("prefix", [b"", DEBUG, BOOT_NOISE, BOOT_NOISE + DEBUG, DEBUG * 20])
def test_leading_garbage_and_debug_text(prefix: bytes) -> None:
    assert detect_protocol(prefix + NATIVE_HELLO) == "native"
    assert detect_protocol(prefix + ROS_TIME_REQUEST) == "rosserial"
    assert detect_protocol(prefix + ROS_CHATTER + DEBUG) == "rosserial"


def test_not_enough_evidence() -> None:
    for data in (b"", DEBUG, BOOT_NOISE, ROS_CHATTER[:-1], NATIVE_HELLO[:-1], b"\xff\xff\x0a"):
        assert detect_protocol(data) is None, data


def test_ff_runs_are_not_rosserial_evidence() -> None:
    v1 = b"\xff\xff\x0a\x00\x08\x00" + bytes(8) + b"\xeb"
    assert detect_protocol(v1 * 3) is None  # protocol v1 firmware is left to the host
    ff_payload = native_frame(Frame(FrameType.BEST_EFFORT, 3, 1, b"\xff" * 40))
    assert detect_protocol(ff_payload) == "native"


def test_first_evidence_wins_inside_one_chunk() -> None:
    assert detect_protocol(NATIVE_HELLO + ROS_CHATTER) == "native"
    assert detect_protocol(ROS_CHATTER + NATIVE_HELLO) == "rosserial"
    assert detect_protocol(DEBUG + ROS_TIME_REQUEST + DEBUG + NATIVE_HELLO) == "rosserial"


@SETTINGS
@given(
    st.binary(max_size=200).filter(lambda b: b"\xff\xfe" not in b and b"\x00" not in b),
    st.sampled_from([("native", NATIVE_HELLO), ("rosserial", ROS_CHATTER)]),
    st.lists(st.integers(0, 400), max_size=8),
)
def test_incremental_feeding(garbage: bytes, case: tuple[str, bytes], cuts: list[int]) -> None:
    expected, frame = case
    stream = garbage + b"\x00" + frame + DEBUG
    detector = ProtocolDetector()
    results = []
    start = 0
    for cut in [*sorted({c % (len(stream) + 1) for c in cuts}), len(stream)]:
        results.append(detector.feed(stream[start:cut]))
        start = max(start, cut)
    assert results[-1] == expected == detector.result
    decided = [r for r in results if r is not None]
    assert all(r == expected for r in decided)
    assert detector.feed(NATIVE_HELLO if expected == "rosserial" else ROS_CHATTER) == expected


@SETTINGS
@given(st.binary(max_size=3000))
def test_random_bytes_never_raise(data: bytes) -> None:
    result = detect_protocol(data)
    assert result in (None, "native", "rosserial")
