"""A node on UdpHardware on the Uno (``hwbridge/hardware_udp.h``'s plain Arduino branch, as with an
Ethernet shield) takes a new session id at every boot, in simavr (PROTOCOL.md 2.10).

The sketch's UDP class prints each datagram on the UART as a line of hex; no bridge answers, so
the node keeps sending HELLOs, each with the session id it chose at boot. In simavr the clock
and A0 read the same at every boot, as on a board that waits for nothing: the ids differ only
through the count of boots (``hwbridge/boot_count.h``)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from hwbridge.errors import HwBridgeError
from hwbridge.firmware.sim import SimAvr
from hwbridge.firmware.sim.examples import build_sketch_for_sim
from hwbridge.links import Link, open_link
from hwbridge.protocols.native.control import HelloMsg, decode_control
from hwbridge.protocols.native.framing import Frame, NativeDatagramFraming

SKETCH = Path(__file__).with_name("sketches") / "UdpBootHello"


def _next_new_session(link: Link, seen: list[int], timeout: float = 20.0) -> int:
    """Read the UART's datagram lines until a HELLO names a session id not in ``seen``."""
    framing = NativeDatagramFraming(max_payload=64)
    buffered = b""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        buffered += link.read(4096, timeout=0.2)
        *lines, buffered = buffered.split(b"\n")
        for line in lines:
            try:
                items = framing.decode(bytes.fromhex(line.decode("ascii")))
            except ValueError:  # a line cut by a reset
                continue
            for item in items:
                if isinstance(item, Frame) and item.channel == 0 and item.payload[:1] == b"\x01":
                    hello = decode_control(item.payload)
                    assert isinstance(hello, HelloMsg)
                    if hello.session not in seen:
                        return hello.session
    raise AssertionError(f"no HELLO with a session id other than {seen} in {timeout} s")


def test_each_boot_of_a_udp_node_has_its_own_session_id(runner: Path) -> None:
    try:
        elf = build_sketch_for_sim(SKETCH)
    except HwBridgeError as exc:
        pytest.skip(f"UdpBootHello does not build here: {str(exc).splitlines()[0]}")
    sim = SimAvr(elf).start()
    link = open_link(f"{sim.url}?baud=115200")
    try:
        sessions = [_next_new_session(link, [])]
        for _ in range(2):
            sim.reset()
            sessions.append(_next_new_session(link, sessions))
        assert len(set(sessions)) == 3
    finally:
        link.close()
        sim.close()
