"""Benchmark of the native framing layer against pymavlink's MAVLink 2 parser.

Run with no arguments; prints one JSON object per line:

- ``framing_decode``: frames per second decoded from a byte stream fed in 4 KiB chunks,
  hwbridge's :class:`FrameDecoder` against ``MAVLink.parse_buffer`` of pymavlink (MAVLink 2,
  unsigned), for payloads of 16 and 200 bytes;
- ``framing_encode``: frames per second encoded (``encode_frame`` against ``msg.pack``);
- ``framing_overhead``: wire bytes per payload byte of hwbridge, rosserial and MAVLink 2.

With ``--hotpath`` it measures instead each speed trick of ``protocols/native/_hotpath.py``
against the plain code it replaces, in one run, through public names only (``hotpath_*`` lines:
``hwbridge_per_s``/``hwbridge_ns`` the trick, ``peer_per_s``/``peer_ns`` the plain code,
``ratio`` how many times faster the trick is). Each is the best of ``--repeats`` ``timeit``
runs of ``--number`` executions of one statement.

The two sides do the job their protocol defines: hwbridge returns frames with the payload as
bytes (its bridge never decodes payloads), pymavlink returns message objects with decoded fields
(its only parse API). pymavlink runs as installed: its parser is Python, and its CRC uses the
``fastcrc`` extension when that is importable (reported as ``peer_impl``). Timings are the best
of a few repeats with ``time.perf_counter`` (``timeit`` for ``--hotpath``).
"""

from __future__ import annotations

import argparse
import json
import platform
import random
import sys
import time
import timeit
from collections.abc import Callable
from importlib import metadata
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from hwbridge.protocols.native.framing import (
    Frame,
    FrameDecoder,
    FrameType,
    encode_frame,
    frame_overhead,
)

CHUNK = 4096
ROSSERIAL_OVERHEAD = 8  # FF FE, length (2), length checksum, topic id (2), checksum
MAVLINK2_OVERHEAD = 12  # 10-byte header and 2-byte CRC, unsigned
V2_EXTENSION_HEADER = 5  # target_network, target_system, target_component, message_type (2)


def best_rate(count: int, run: Callable[[], object], repeats: int) -> float:
    """Items per second of the fastest of ``repeats`` runs."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - start)
    return count / best


def chunks_of(stream: bytes) -> list[bytes]:
    return [stream[i : i + CHUNK] for i in range(0, len(stream), CHUNK)]


def native_frames(payload: int, count: int, rng: random.Random) -> list[Frame]:
    return [
        Frame(FrameType.BEST_EFFORT, 1 + i % 8, i & 0xFF, rng.randbytes(payload))
        for i in range(count)
    ]


def mavlink_messages(payload: int, count: int, rng: random.Random) -> tuple[str, list[Any]]:
    """MAVLink 2 messages whose payload on the wire is ``payload`` bytes (16 or ~200)."""
    if payload == 16:
        # SCALED_PRESSURE: uint32, 2 floats, int16 and the int16 extension = 16 bytes.
        return "SCALED_PRESSURE", [
            mavlink2.MAVLink_scaled_pressure_message(
                i + 1, 1013.25 + rng.random(), rng.random() + 0.5, 2100 + i % 50, 263
            )
            for i in range(count)
        ]
    # V2_EXTENSION carries opaque bytes; MAVLink 2 drops trailing zeros, so the data ends non-zero.
    data_size = payload - V2_EXTENSION_HEADER
    messages = []
    for _ in range(count):
        data = [*rng.randbytes(data_size - 1), rng.randrange(1, 256)]
        data += [0] * (249 - data_size)
        messages.append(mavlink2.MAVLink_v2_extension_message(0, 1, 1, 1000, data))
    return "V2_EXTENSION", messages


def peer_info() -> dict[str, Any]:
    """How pymavlink is running: it has no native parser in this version; CRC may be native."""
    native_parser = getattr(mavlink2, "mavnative", None) is not None
    native_crc = getattr(mavlink2, "mcrf4xx", None) is not None
    return {
        "peer_version": metadata.version("pymavlink"),
        "peer_impl": ("native" if native_parser else "python")
        + (" parser, fastcrc CRC" if native_crc else " parser, python CRC"),
        "peer_native_parser": native_parser,
    }


def bench_size(payload: int, count: int, repeats: int) -> list[dict[str, Any]]:
    rng = random.Random(payload)
    frames = native_frames(payload, count, rng)
    wires = [encode_frame(f) for f in frames]
    native_chunks = chunks_of(b"".join(wires))

    sender = mavlink2.MAVLink(file=None, srcSystem=1, srcComponent=1)
    peer_message, messages = mavlink_messages(payload, count, rng)
    packets = [m.pack(sender) for m in messages]
    peer_payload = len(packets[0]) - MAVLINK2_OVERHEAD
    mav_chunks = chunks_of(b"".join(packets))

    def native_decode() -> None:
        decoder = FrameDecoder()
        got = 0
        for chunk in native_chunks:
            got += len(decoder.feed(chunk))
        if got != count:
            raise RuntimeError(f"hwbridge decoded {got} of {count} frames")

    def mavlink_decode() -> None:
        parser = mavlink2.MAVLink(file=None)
        got = 0
        for chunk in mav_chunks:
            got += len(parser.parse_buffer(chunk) or ())
        if got != count:
            raise RuntimeError(f"pymavlink decoded {got} of {count} messages")

    def native_encode() -> None:
        for frame in frames:
            encode_frame(frame)

    def mavlink_encode() -> None:
        for message in messages:
            message.pack(sender)

    common = {"payload": payload, "frames": count, "peer": "pymavlink"}
    peer = {"peer_message": peer_message, "peer_payload": peer_payload, **peer_info()}
    lines = []
    for bench, ours, theirs in (
        ("framing_decode", native_decode, mavlink_decode),
        ("framing_encode", native_encode, mavlink_encode),
    ):
        native_rate = best_rate(count, ours, repeats)
        peer_rate = best_rate(count, theirs, repeats)
        lines.append(
            {
                "bench": bench,
                **common,
                "hwbridge_per_s": round(native_rate),
                "peer_per_s": round(peer_rate),
                "ratio": round(native_rate / peer_rate, 2),
                **peer,
            }
        )
    native_wire = sum(len(w) for w in wires) / count
    lines.append(
        {
            "bench": "framing_overhead",
            "payload": payload,
            "native_overhead_bytes_max": frame_overhead(payload),
            "native_overhead_bytes_mean": round(native_wire - payload, 3),
            "native_bytes_per_payload_byte": round(native_wire / payload, 3),
            "rosserial_bytes_per_payload_byte": round((payload + ROSSERIAL_OVERHEAD) / payload, 3),
            "mavlink2_bytes_per_payload_byte": round((payload + MAVLINK2_OVERHEAD) / payload, 3),
        }
    )
    return lines


HOTPATH_CASES: list[tuple[str, str, str, str]] = [
    # (bench, peer, the trick, the plain code it replaces): statements run by timeit with the
    # names of hotpath_namespace() as globals, the way the hot paths use them.
    (
        "hotpath_make_frame",
        "Frame_constructor",
        "make_frame(BEST_EFFORT, 3, 7, payload, WHOLE)",
        "Frame(BEST_EFFORT, 3, 7, payload, WHOLE)",
    ),
    (
        "hotpath_message_event",
        "Message_constructor",
        "message(3, payload, 7)",
        "Message(3, payload, 7)",
    ),
    (
        "hotpath_enum_global",
        "enum_class_attribute",
        "state is CONNECTED",
        "state is SessionState.CONNECTED",
    ),
]
"""Each trick of ``protocols/native/_hotpath.py`` reachable through public names. The
SERVICE_REQUEST/SERVICE_RESPONSE decoders' generic path only runs on a payload too short to
decode (it is there for its error message), so it has no public entry to time against."""


def hotpath_namespace() -> dict[str, Any]:
    """The globals the hot-path statements run with (public names only)."""
    from hwbridge.protocols.base import Message
    from hwbridge.protocols.native._hotpath import (
        BEST_EFFORT,
        CONNECTED,
        WHOLE,
        make_frame,
        message,
    )
    from hwbridge.protocols.native.session import SessionState

    return {
        "BEST_EFFORT": BEST_EFFORT,
        "CONNECTED": CONNECTED,
        "WHOLE": WHOLE,
        "Frame": Frame,
        "Message": Message,
        "SessionState": SessionState,
        "make_frame": make_frame,
        "message": message,
        "payload": b"\x0c\x00\x00\x000123456789ab",
        "state": SessionState.CONFIGURING,
    }


def bench_hotpath(number: int, repeats: int) -> list[dict[str, Any]]:
    """Each hot-path trick against the plain code it replaces: executions per second of the best
    of ``repeats`` ``timeit`` runs of ``number`` executions (timeit's own loop, no call around
    the statement; its loop costs a few ns an execution, included on both sides)."""
    namespace = hotpath_namespace()
    lines = []
    for bench, peer, trick, plain in HOTPATH_CASES:
        rates = []
        for stmt in (trick, plain):
            timer = timeit.Timer(stmt, globals=namespace)
            rates.append(number / min(timer.repeat(repeat=repeats, number=number)))
        fast, slow = rates
        lines.append(
            {
                "bench": bench,
                "hwbridge_per_s": round(fast),
                "hwbridge_ns": round(1e9 / fast, 1),
                "peer": peer,
                "peer_per_s": round(slow),
                "peer_ns": round(1e9 / slow, 1),
                "ratio": round(fast / slow, 2),
                "number": number,
                "repeats": repeats,
                "python": platform.python_version(),
            }
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--frames", type=int, default=20_000, help="frames per run")
    parser.add_argument("--repeats", type=int, default=5, help="runs per measurement (best)")
    parser.add_argument(
        "--hotpath", action="store_true", help="measure the hot-path tricks instead"
    )
    parser.add_argument(
        "--number", type=int, default=1_000_000, help="executions per --hotpath timeit run"
    )
    args = parser.parse_args(argv)
    if args.hotpath:
        for line in bench_hotpath(args.number, args.repeats):
            print(json.dumps(line), flush=True)
        return 0
    for payload in (16, 200):
        for line in bench_size(payload, args.frames, args.repeats):
            print(json.dumps(line), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
