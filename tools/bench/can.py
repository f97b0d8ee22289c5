"""Benchmark of the native protocol on CAN against pycyphal (Cyphal/CAN), in one run.

Run with no arguments; prints one JSON object per line, per message type (``std_msgs/UInt32``,
``sensor_msgs/Imu``, ``nav_msgs/Odometry``, ROS 1 serialized):

- ``can_ceiling``: what classic CAN at 1 Mbit/s can carry at most, from frame bit lengths with
  worst-case stuffing (``hwbridge.links.can.frame_bits``: 29-bit id, interframe space included):
  messages per second (``hwbridge_per_s``/``peer_per_s``), the frames and bus bits one message
  takes, the frames/s ceiling for that mix (``*_frames_per_s``), and the payload efficiency
  (payload bits / bus bits). hwbridge sends one native datagram per fragment at the native MTU
  (``--mtu``, 1024: the host's, which a format-2 board negotiates up to its largest message) as
  one CAN transfer each (protocols/can/CAN.md), in format 2 (``format``: the native header in the
  id and the tail byte, no native CRC-16); pycyphal sends the message as one Cyphal/CAN transfer
  (7 bytes a frame, a 2-byte CRC past one frame). A message fragmented at the native MTU goes
  as one chained transfer (CAN.md version 3, §12, ``chained``: the fragments' bytes end to end,
  one transfer CRC). The frame counts are checked against the frames both put on a python-can
  virtual bus. Three more ``can_ceiling`` lines per type, computed in the same run, show the
  board-default MTU of 64: chained (version 3), each fragment its own transfer (``chained``
  false: CAN.md version 2) and format 1 (version 1, every datagram whole with its header and
  CRC-16).
- ``can_virtual_bus``: messages per second each moves through python-can's in-process
  ``virtual`` bus, sender to receiver in one process: hwbridge from one ``can://`` link to
  another (encoding, the links' threads, reassembly), pycyphal from an output session to an
  input session of two ``CANTransport`` objects on ``PythonCANMedia``. ``host_vs_ceiling`` is the
  frames/s hwbridge sustained over the frames/s classic CAN at 1 Mbit/s can carry: above 1, the
  host is not the limit.

Only the transports are compared (no native session, no Cyphal presentation layer): neither
acknowledges or resends here. pycyphal is installed from PyPI (``pip install pycyphal``).
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import sys
import threading
import time
from pathlib import Path
from typing import Any

# This file is named can.py: keep its folder off the path, or "import can" would find it.
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parents[1]))

import can  # noqa: E402

from hwbridge import msg  # noqa: E402
from hwbridge.links.can import CanLink, frame_bits  # noqa: E402
from hwbridge.protocols.can.transport import (  # noqa: E402
    CLASSIC_MTU,
    FORMAT_1,
    FORMAT_2,
    Kind,
    TransferEncoder,
)
from hwbridge.protocols.native.framing import (  # noqa: E402
    FrameType,
    encode_datagram,
    fragment,
)
from tools.bench._common import emit  # noqa: E402

BITRATE = 1_000_000
PEER = "pycyphal"
_channels = itertools.count()


def payloads() -> dict[str, bytes]:
    stamp = {"stamp": 1.5, "frame_id": "imu_link"}
    return {
        "std_msgs/UInt32": msg.encode(msg.from_dict("std_msgs/UInt32", {"data": 7})),
        "sensor_msgs/Imu": msg.encode(
            msg.from_dict(
                "sensor_msgs/Imu",
                {"header": stamp, "orientation": {"w": 1.0}, "linear_acceleration": {"z": 9.81}},
            )
        ),
        "nav_msgs/Odometry": msg.encode(
            msg.from_dict(
                "nav_msgs/Odometry",
                {"header": {"stamp": 1.5, "frame_id": "odom"}, "child_frame_id": "base_link"},
            )
        ),
    }


def hwbridge_datagrams(payload: bytes, mtu: int) -> list[bytes]:
    return [encode_datagram(f) for f in fragment(FrameType.BEST_EFFORT, 1, 0, payload, mtu)]


def hwbridge_frames(
    payload: bytes, mtu: int, fmt: int = FORMAT_2, *, chain: bool = True
) -> list[bytes]:
    encoder = TransferEncoder(5, CLASSIC_MTU)
    chain = chain and fmt == FORMAT_2
    return [
        data
        for d in hwbridge_datagrams(payload, mtu)
        for _, data in encoder.datagram(d, 0, format=fmt, chain=chain)
    ]


def cyphal_frame_lengths(size: int) -> list[int]:
    """Cyphal/CAN on classic CAN: one frame of size + tail byte up to 7 bytes; otherwise the
    payload and a 2-byte CRC in frames of 7 bytes and a tail byte (the last one shorter)."""
    if size <= 7:
        return [size + 1]
    left = size + 2
    lengths = []
    while left:
        take = min(7, left)
        lengths.append(take + 1)
        left -= take
    return lengths


def bus_bits(lengths: list[int]) -> int:
    return sum(frame_bits(length) for length in lengths)


# ------------------------------------------------------------------------------ measurements


def sniff(run: Any, *, skip_claims: bool = False) -> int:
    """Frames seen on a fresh virtual channel while ``run(channel)`` runs (hwbridge's node-id
    claims left out with ``skip_claims``)."""
    channel = f"can-bench-{next(_channels)}"
    sniffer = can.Bus(interface="virtual", channel=channel)
    try:
        run(channel)
        count = 0
        while (message := sniffer.recv(0.2)) is not None:
            if not (skip_claims and (message.arbitration_id >> 24) & 3 == Kind.NODE):
                count += 1
        return count
    finally:
        sniffer.shutdown()


def hwbridge_rate(payload: bytes, mtu: int, count: int, channel: str | None = None) -> float:
    """Messages/s from one can:// link to another (each message: its datagrams)."""
    channel = channel or f"can-bench-{next(_channels)}"
    datagrams = hwbridge_datagrams(payload, mtu)
    sender = CanLink(f"can://virtual/{channel}?node=0&local=5&tx_queue=10000000")
    receiver = CanLink(f"can://virtual/{channel}/node5?rx_queue=10000000")
    sender.open()
    receiver.open()
    # chains go to a peer once its claim said it takes them (the receiver's, at its start)
    deadline = time.monotonic() + 10
    while not (sender.hub and sender.hub.peer_chains.get(0)) and time.monotonic() < deadline:
        time.sleep(0.01)
    expected = count * len(datagrams)
    done = threading.Event()
    got = [0]

    def read() -> None:
        while got[0] < expected:
            if receiver.read(4096, 5.0):
                got[0] += 1
            elif done.is_set():
                return
        done.set()

    reader = threading.Thread(target=read, daemon=True)
    try:
        time.sleep(0.05)
        reader.start()
        start = time.perf_counter()
        for _ in range(count):
            for datagram in datagrams:
                sender.write(datagram)
        finished = done.wait(120)
        elapsed = time.perf_counter() - start
        done.set()
        if not finished or got[0] < expected:
            raise RuntimeError(f"hwbridge: {got[0]} of {expected} datagrams arrived")
        return count / elapsed
    finally:
        reader.join(6)
        sender.close()
        receiver.close()


def cyphal_rate(payload: bytes, count: int, channel: str | None = None) -> float:
    """Transfers/s from a pycyphal output session to an input session on one virtual bus."""
    import pycyphal.transport as pt
    from pycyphal.transport.can import CANTransport
    from pycyphal.transport.can.media.pythoncan import PythonCANMedia

    channel = channel or f"can-bench-{next(_channels)}"

    async def run() -> float:
        loop = asyncio.get_running_loop()
        tx = CANTransport(PythonCANMedia(f"virtual:{channel}", BITRATE, CLASSIC_MTU), 11)
        rx = CANTransport(PythonCANMedia(f"virtual:{channel}", BITRATE, CLASSIC_MTU), 12)
        meta = pt.PayloadMetadata(extent_bytes=len(payload) + 64)
        subject = pt.MessageDataSpecifier(1234)
        out = tx.get_output_session(pt.OutputSessionSpecifier(subject, None), meta)
        inp = rx.get_input_session(pt.InputSessionSpecifier(subject, None), meta)
        got = 0

        async def receive() -> None:
            nonlocal got
            while got < count:
                transfer = await inp.receive(loop.time() + 5.0)
                if transfer is None:
                    return
                got += 1

        receiver = asyncio.create_task(receive())
        await asyncio.sleep(0.05)
        start = time.perf_counter()
        for index in range(count):
            transfer = pt.Transfer(
                pt.Timestamp.now(), pt.Priority.NOMINAL, index, [memoryview(payload)]
            )
            await out.send(transfer, loop.time() + 5.0)
        await receiver
        elapsed = time.perf_counter() - start
        tx.close()
        rx.close()
        if got < count:
            raise RuntimeError(f"pycyphal: {got} of {count} transfers arrived")
        return count / elapsed

    return asyncio.run(run())


def main() -> int:
    parser = argparse.ArgumentParser(description="CAN transfers: hwbridge against pycyphal")
    parser.add_argument("--mtu", type=int, default=1024, help="native frame payload MTU (1024)")
    parser.add_argument("--frames", type=int, default=20000, help="frames per measurement")
    args = parser.parse_args()
    for type_name, payload in payloads().items():
        ours = hwbridge_frames(payload, args.mtu)
        ours_lengths = [len(f) for f in ours]
        theirs_lengths = cyphal_frame_lengths(len(payload))
        ours_bits, theirs_bits = bus_bits(ours_lengths), bus_bits(theirs_lengths)
        seen_ours = sniff(lambda ch, p=payload: hwbridge_rate(p, args.mtu, 5, ch), skip_claims=True)
        seen_theirs = sniff(lambda ch, p=payload: cyphal_rate(p, 5, ch))
        case = {"type": type_name, "payload": len(payload), "bitrate": BITRATE}
        ceiling_ours = BITRATE / ours_bits
        emit(
            "can_ceiling",
            case,
            ceiling_ours,
            PEER,
            BITRATE / theirs_bits,
            hwbridge_frames=len(ours),
            peer_frames=len(theirs_lengths),
            frames_checked_on_bus=seen_ours == 5 * len(ours)
            and seen_theirs == 5 * len(theirs_lengths),
            hwbridge_bits=ours_bits,
            peer_bits=theirs_bits,
            hwbridge_frames_per_s=round(ceiling_ours * len(ours), 1),
            peer_frames_per_s=round(BITRATE / theirs_bits * len(theirs_lengths), 1),
            hwbridge_efficiency=round(8 * len(payload) / ours_bits, 3),
            peer_efficiency=round(8 * len(payload) / theirs_bits, 3),
            mtu=args.mtu,
            format=FORMAT_2,
            chained=True,
        )
        for fmt, mtu, chain in ((FORMAT_2, 64, True), (FORMAT_2, 64, False), (FORMAT_1, 64, False)):
            lengths = [len(f) for f in hwbridge_frames(payload, mtu, fmt, chain=chain)]
            bits = bus_bits(lengths)
            emit(
                "can_ceiling",
                case,
                BITRATE / bits,
                PEER,
                BITRATE / theirs_bits,
                hwbridge_frames=len(lengths),
                peer_frames=len(theirs_lengths),
                hwbridge_bits=bits,
                peer_bits=theirs_bits,
                mtu=mtu,
                format=fmt,
                chained=chain,
            )
        messages = max(20, args.frames // len(ours))
        peer_messages = max(20, args.frames // len(theirs_lengths))
        ours_rate = hwbridge_rate(payload, args.mtu, messages)
        theirs_rate = cyphal_rate(payload, peer_messages)
        emit(
            "can_virtual_bus",
            case,
            ours_rate,
            PEER,
            theirs_rate,
            hwbridge_frames_per_s=round(ours_rate * len(ours), 1),
            peer_frames_per_s=round(theirs_rate * len(theirs_lengths), 1),
            host_vs_ceiling=round(ours_rate / ceiling_ours, 2),
            mtu=args.mtu,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
