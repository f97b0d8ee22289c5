"""``UdpHardware`` (firmware/HwBridge/src/hwbridge/hardware_udp.h) against the Python reference,
property-based: the harness sketch ``sketches/UdpHardwareHarness`` (built with ``--board host``)
runs it over a scripted UDP class and takes commands on stdin.

- Every frame the node writes goes out as one datagram equal to the reference's
  ``encode_datagram`` (PROTOCOL.md 1.13), to the discovery address until a host is known and
  to the host after.
- Discovery (1.14): among any datagrams from any addresses (frames and garbage), the host is the
  source of the first valid frame; the node is given exactly the valid frames from the host, in
  order; every datagram that is no frame is counted bad, every valid frame from elsewhere
  foreign; nothing is ever given twice or lost uncounted.
- With the host set, the same holds with that host from the start.
"""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hwbridge.protocols.native.framing import (
    Frag,
    Frame,
    FrameType,
    NativeDatagramFraming,
    encode_datagram,
)

SKETCH = Path(__file__).parent / "sketches" / "UdpHardwareHarness"
DISCOVERY = ("10.0.0.255", 2324)
BUFFER = 300
"""The harness's kBuffer: the largest body the hardware takes or sends."""

pytestmark = pytest.mark.skipif(
    shutil.which("g++") is None, reason="g++ is not installed (Debian package g++)"
)


class Harness:
    def __init__(self, exe: Path) -> None:
        self.process = subprocess.Popen(
            [str(exe)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )

    def ask(self, line: str) -> str:
        assert self.process.stdin is not None and self.process.stdout is not None
        self.process.stdin.write(line + "\n")
        self.process.stdin.flush()
        answer = self.process.stdout.readline().strip()
        assert answer and not answer.startswith("error"), (line, answer)
        return answer

    def close(self) -> None:
        if self.process.stdin is not None:
            self.process.stdin.close()
        self.process.wait(10)
        if self.process.stdout is not None:
            self.process.stdout.close()


@pytest.fixture(scope="module")
def harness(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Harness]:
    from hwbridge.firmware.build import build_host_sketch

    running = Harness(build_host_sketch(SKETCH, tmp_path_factory.mktemp("udp_harness")))
    yield running
    running.close()


frames = st.builds(
    Frame,
    st.sampled_from(list(FrameType)),
    st.integers(0, 255),
    st.integers(0, 255),
    st.binary(max_size=64),
    st.sampled_from(list(Frag)),
)
addresses = st.tuples(
    st.sampled_from(["10.0.0.7", "10.0.0.8", "192.168.1.2"]), st.sampled_from([2324, 40000])
)
# a datagram: a valid frame, a damaged one (one bit flipped), or any bytes
datagrams = st.one_of(
    frames.map(encode_datagram),
    st.tuples(frames, st.integers(0, 10_000)).map(lambda fb: _flip(encode_datagram(fb[0]), fb[1])),
    st.binary(min_size=1, max_size=80),
)


def _flip(data: bytes, bit: int) -> bytes:
    out = bytearray(data)
    out[(bit // 8) % len(out)] ^= 1 << (bit % 8)
    return bytes(out)


def _is_frame(data: bytes) -> bool:
    """The reference's verdict, with the harness's buffer as the payload limit."""
    events = NativeDatagramFraming(max_payload=BUFFER - 5).decode(data)
    return len(events) == 1 and isinstance(events[0], Frame)


def _stats(harness: Harness) -> dict[str, int]:
    names = ("in", "out", "bad", "foreign", "oversize", "failures", "discoveries", "known")
    fields = harness.ask("stats").split()[1:]
    return dict(zip(names, map(int, fields), strict=True))


SETTINGS = settings(
    max_examples=150,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)


@SETTINGS
@given(frame=frames)
def test_each_frame_goes_out_as_one_datagram_as_the_reference_encodes_it(
    harness: Harness, frame: Frame
) -> None:
    harness.ask("reset")
    line = f"frame {frame.type} {frame.frag} {frame.channel} {frame.seq} {frame.payload.hex()}"
    out = harness.ask(line).split()
    assert out[:3] == ["out", DISCOVERY[0], str(DISCOVERY[1])]  # no host known: discovery
    body = bytes.fromhex(out[3]) if len(out) > 3 else b""
    assert body == encode_datagram(frame)


@SETTINGS
@given(
    arrivals=st.lists(st.tuples(addresses, datagrams), max_size=25),
    fixed=st.one_of(st.none(), addresses),
)
def test_the_host_is_the_first_valid_frames_source_and_only_its_frames_pass(
    harness: Harness,
    arrivals: list[tuple[tuple[str, int], bytes]],
    fixed: tuple[str, int] | None,
) -> None:
    harness.ask("reset" if fixed is None else f"reset {fixed[0]} {fixed[1]}")
    host = fixed
    expected_bad = expected_foreign = 0
    for (ip, port), data in arrivals:
        answer = harness.ask(f"in {ip} {port} {data.hex()}")
        got = bytes.fromhex(answer.split()[1]) if answer.startswith("got") else None
        if not _is_frame(data):
            expected_bad += 1
            assert got is None
            continue
        if host is None:
            host = (ip, port)  # discovery: the first valid frame's source
        if (ip, port) == host:
            assert got == data
        else:
            expected_foreign += 1
            assert got is None
    stats = _stats(harness)
    assert stats["bad"] == expected_bad
    assert stats["foreign"] == expected_foreign
    assert stats["in"] + stats["bad"] + stats["foreign"] == len(arrivals)  # none unaccounted
    assert stats["known"] == (host is not None)
    assert stats["discoveries"] == (fixed is None and host is not None)

    # and frames now go to the host (or still to the discovery address)
    out = harness.ask("frame 0 0 0 0 00").split()
    assert (out[1], int(out[2])) == (host if host is not None else DISCOVERY)


def test_a_datagram_larger_than_the_buffer_is_dropped_and_counted(harness: Harness) -> None:
    harness.ask("reset")
    big = encode_datagram(Frame(FrameType.BEST_EFFORT, 1, 0, bytes(BUFFER)))  # body BUFFER + 5
    assert harness.ask(f"in 10.0.0.7 2324 {big.hex()}") == "none"
    assert _stats(harness)["oversize"] == 1
    assert harness.ask(f"frame 0 0 1 0 {bytes(BUFFER).hex()}") == "none"  # too big to send
    assert _stats(harness)["oversize"] == 2
