"""A rosserial host and a Mega reset under it: Debian's stk500v2 bootloader takes bytes that come
after a reset as an upload and waits 5 s after each one (``tests/protocols/stk500v2.py``). The
hosts the runtime builds leave it that silence (calls in bursts with pauses; with a
``start_delay``, requests 6 s apart); a host asking every second would hold it there for good."""

from __future__ import annotations

import pytest

from hwbridge.protocols.base import Connected
from hwbridge.protocols.calling import BOOTLOADER_QUIET, CALL_BURST
from hwbridge.protocols.registry import SessionContext
from hwbridge.protocols.rosserial.device import RosserialDevice, TimeSynced
from hwbridge.protocols.rosserial.host import RosserialHost
from hwbridge.protocols.rosserial.spec import new_session
from tests.protocols.stk500v2 import Stk500v2
from tests.protocols.test_rosserial_host import REG, WALL0, Sim, board


def _restarted(device: RosserialDevice) -> Stk500v2:
    def start(_now: float) -> RosserialDevice:
        device.reset()  # the sketch starts afresh: unconfigured, silent until asked
        return device

    return Stk500v2(start, reset_at=0.0)


def _mega_reset(host: RosserialHost, limit: float) -> tuple[Sim, Stk500v2, float]:
    """``host`` connects to a board, which resets into its bootloader 2.4 s after its last time
    request (so that the host's silence probe, 3 s after it, lands in the bootloader's first
    second); run until the host has the board's table again, or ``limit`` seconds."""
    sim = Sim(board())
    sim.host = host
    sim.connect()
    device = sim.device
    assert device is not None
    sim.device_events.clear()
    sim.run_until(lambda: bool(sim.device_of(TimeSynced)), limit=10)
    sim.run(2.4)
    sim.take()
    bootloader = _restarted(device)
    bootloader.reset_at = reset_at = sim.t
    sim.device = bootloader  # type: ignore[assignment]  # the bytes the board's UART sees
    end = sim.t + limit
    while sim.t < end and not (bootloader.running and device.configured and sim.host_of(Connected)):
        sim.step()
    return sim, bootloader, reset_at


@pytest.mark.parametrize("start_delay", [0.0, 2.0])
def test_a_mega_reset_under_the_runtimes_host_comes_back(start_delay: float) -> None:
    host = new_session(SessionContext(REG, False, 0.0, WALL0, start_delay=start_delay))
    assert isinstance(host, RosserialHost)
    sim, bootloader, reset_at = _mega_reset(host, limit=40.0)
    assert bootloader.bytes_taken > 0, "the reset board was not probed in its first second"
    assert bootloader.running and sim.host_of(Connected)
    # probing from 3 s after the last time request, at worst a burst and a pause, then the
    # bootloader's 5 s and the next request
    assert sim.t - reset_at < 3.0 + CALL_BURST + BOOTLOADER_QUIET + 1.0
    requests = sim.host.stats.topic_requests
    sim.run(60.0)
    assert sim.host.stats.topic_requests == requests, "a healthy board is not asked again"


def test_a_host_asking_every_second_holds_a_reset_mega_in_its_bootloader() -> None:
    """Why the runtime's hosts pause: without (``call_burst`` 0), the board never comes back."""
    _, stuck, _ = _mega_reset(RosserialHost(REG, now=0.0), limit=60.0)
    assert stuck.bytes_taken > 0 and not stuck.running
