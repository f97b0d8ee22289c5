"""A host that listens first (``HostConfig.listen_first``, PROTOCOL.md 2.5): for boards whose
bootloader takes any byte after a reset as the start of an upload and waits for the next one (a
Mega's stk500v2, 5 s after each byte), the host never keeps talking to a board it does not hear.
It answers the board's HELLOs, retries its own only for a ``link_timeout`` after it last heard
the board, and still connects through loss, duplication, reordering and board resets. Without a
start delay, the runtime's stream host calls a silent board in bursts with pauses
(``HostConfig.call_burst``), which let a reset Mega out of its bootloader too."""

from __future__ import annotations

import random
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hwbridge.protocols.calling import may_call
from hwbridge.protocols.errors import HwBridgeTimeoutError
from hwbridge.protocols.native.session import (
    DeviceSession,
    Event,
    HostConfig,
    HostSession,
)
from tests.protocols.lossy import Faults, SimLink
from tests.protocols.stk500v2 import Stk500v2
from tests.protocols.test_native_session import BOARD, LINK_FAULTS, SETTINGS, TOPICS, errors

LISTEN = HostConfig(listen_first=True)


class Watched:
    """A host session whose bytes in and out are timed: ``heard`` (deliveries of the board's
    bytes, garbled ones too) and ``said`` (the host's writes)."""

    def __init__(self, host: HostSession) -> None:
        self.host = host
        self.heard: list[float] = []
        self.said: list[float] = []
        self._now = 0.0

    def receive_data(self, data: bytes, now: float) -> list[Event]:
        self._now = now
        if data:
            self.heard.append(now)
        return self.host.receive_data(data, now)

    def tick(self, now: float) -> list[Event]:
        self._now = now
        return self.host.tick(now)

    def data_to_send(self) -> bytes:
        out = self.host.data_to_send()
        if out:
            self.said.append(self._now)
        return out

    def __getattr__(self, name: str) -> Any:
        return getattr(self.host, name)


def _link(seed: int, faults: Faults | None = None) -> tuple[SimLink, Watched]:
    watched = Watched(HostSession(LISTEN, rng=random.Random(seed)))
    device = DeviceSession(BOARD, TOPICS, rng=random.Random(seed + 1))
    link = SimLink(
        watched,  # type: ignore[arg-type]  # the host's methods SimLink calls, timed
        device,
        seed=seed,
        h2d=faults,
        d2h=Faults(**vars(faults)) if faults is not None else None,
    )
    return link, watched


def _talked_only_when_heard(watched: Watched, window: float) -> None:
    """Every write of the host came within ``window`` of bytes from the board."""
    for t in watched.said:
        last = max((h for h in watched.heard if h <= t), default=None)
        assert last is not None, f"the host wrote at {t:.3f} s, never having heard the board"
        assert t - last <= window + 1e-9, (
            f"the host wrote at {t:.3f} s, {t - last:.3f} s after the board last spoke"
        )


def test_a_silent_board_gets_no_byte_and_one_report() -> None:
    """A board held in its bootloader says nothing: the host writes nothing to it in a minute,
    says once that no HELLO came, and has no timer left to wake it (a default host would have
    sent 240 HELLOs)."""
    link, watched = _link(3)
    link.d2h.faults.cut = True
    link.run(60.0)
    assert watched.said == []
    assert link.host.stats.hellos_sent == 0
    (report,) = errors(link.host_events)
    assert isinstance(report, HwBridgeTimeoutError) and "no HELLO from the board" in str(report)
    assert link.host.next_deadline() is None


def test_the_board_speaks_first_and_the_host_answers_at_once() -> None:
    link, watched = _link(5)
    assert link.run(5.0, until=lambda: link.host.connected and link.device.connected)
    # the first byte the host wrote answered the board's first HELLO, at the moment it came
    assert watched.said[0] == watched.heard[0]


@SETTINGS
@given(
    **LINK_FAULTS,
    outages=st.lists(
        st.tuples(st.floats(0.1, 4.0), st.floats(0.1, 8.0), st.booleans()), max_size=4
    ),
)
def test_the_host_talks_only_to_a_board_it_hears_and_connects_after_each_outage(
    seed: int,
    loss: float,
    duplicate: float,
    reorder: float,
    outages: list[tuple[float, float, bool]],
) -> None:
    """Periods up, then silent (a reset board in its bootloader, swallowing what it is sent; or
    a board that restarts at the end of it), with loss, corruption, duplication and reordering:
    the host never writes more than a link timeout after it last heard the board, and connects
    again once the board is back."""
    faults = Faults(
        drop=loss / 2, corrupt=loss / 2, duplicate=duplicate, reorder=reorder, max_chunk=9
    )
    link, watched = _link(seed, faults)
    for number, (up, down, restart) in enumerate(outages):
        link.run(up)
        link.d2h.faults.cut = link.h2d.faults.cut = True
        link.run(down)
        link.d2h.faults.cut = link.h2d.faults.cut = False
        if restart:
            device = DeviceSession(BOARD, TOPICS, rng=random.Random(seed + 100 + number))
            link.reset_device(device)
    connected = link.run(60.0, until=lambda: link.host.connected and link.device.connected)
    assert connected, errors(link.host_events + link.device_events)
    _talked_only_when_heard(watched, link.host.config.link_timeout)


# ---------------------------------------------------------------------------------------------
# calls in bursts (HostConfig.call_burst), and a Mega reset under the runtime's hosts


def test_a_silent_board_is_called_in_bursts_with_pauses() -> None:
    """A host with ``call_burst`` sends HELLOs to a board it never hears only in bursts (5 s,
    then 6, 9, 13.5 s of silence...): the pauses are what a Mega's bootloader needs to give up
    on the bytes it took."""
    watched = Watched(HostSession(HostConfig(call_burst=5.0, call_pause=6.0)))
    device = DeviceSession(BOARD, TOPICS, rng=random.Random(2))
    link = SimLink(watched, device, d2h=Faults(cut=True))  # type: ignore[arg-type]
    link.run(60.0)
    assert watched.said and watched.heard == []
    for t in watched.said:
        assert may_call(t, 0.0, 5.0, 6.0), f"a HELLO at {t:.3f} s, in a pause"
    for start in (0.0, 11.0, 25.0, 43.5):  # every burst is used
        assert any(start <= t < start + 5.0 for t in watched.said), start


def _session_from_the_runtime(start_delay: float) -> HostSession:
    from hwbridge import msg
    from hwbridge.protocols.native.spec import new_session
    from hwbridge.protocols.registry import SessionContext

    context = SessionContext(msg.registry(), False, 0.0, 0.0, start_delay=start_delay)
    return new_session(context)


def _reset_under(host: HostSession) -> tuple[bool, Stk500v2]:
    """Connect ``host`` to a board, reset the board into its bootloader a second later; whether
    the sketch and the host are connected again within a minute, and the bootloader."""
    link = SimLink(host, DeviceSession(BOARD, TOPICS, rng=random.Random(7)), seed=7)
    assert link.run(10.0, until=lambda: link.host.connected and link.device.connected)
    link.run(1.0)

    def sketch(_now: float) -> DeviceSession:
        return DeviceSession(BOARD, TOPICS, rng=random.Random(8))

    bootloader = Stk500v2(sketch, reset_at=link.device_time(link.now))
    link.reset_device(bootloader)  # type: ignore[arg-type]
    back = link.run(60.0, until=lambda: bootloader.connected and link.host.connected)
    assert bootloader.bytes_taken > 0, "the host said nothing in the bootloader's first second"
    return back, bootloader


@pytest.mark.parametrize("start_delay", [0.0, 2.0])
def test_a_mega_reset_under_the_runtimes_host_comes_back(start_delay: float) -> None:
    """The board resets into its stk500v2 bootloader while connected; the host's heartbeats (and
    HELLOs) reach the bootloader in its first second. The runtime's stream host pauses (with a
    start delay it listens first) and the sketch is back."""
    back, bootloader = _reset_under(_session_from_the_runtime(start_delay))
    assert back and bootloader.running


def test_a_host_calling_without_pause_holds_a_reset_mega_in_its_bootloader() -> None:
    """Why the runtime's stream hosts pause: without (``call_burst`` 0), never back."""
    back, bootloader = _reset_under(HostSession())
    assert not back and not bootloader.running
