"""A rosserial host and a Mega reset under it: Debian's stk500v2 bootloader takes bytes that come
after a reset as an upload and waits 5 s after each one. The host the runtime builds for a board
with a ``start_delay`` leaves it that silence; the default host would not."""

from __future__ import annotations

from hwbridge.protocols.base import Connected
from hwbridge.protocols.registry import BOOTLOADER_QUIET, SessionContext
from hwbridge.protocols.rosserial.device import DeviceEvent, RosserialDevice, TimeSynced
from hwbridge.protocols.rosserial.host import RosserialHost
from hwbridge.protocols.rosserial.spec import new_session
from tests.protocols.test_rosserial_host import REG, WALL0, Sim, board


class Stk500v2:
    """What a Mega 2560 with Debian's stk500v2 bootloader does after a reset, as the device's
    link sees it: silent; a byte within the first second makes it wait for an upload, and it
    leaves for the sketch (``device``, started afresh) 5 s after the last byte it received;
    without one it leaves after that first second."""

    FIRST_WINDOW = 1.0
    WAIT_AFTER_BYTE = 5.0

    def __init__(self, device: RosserialDevice, reset_at: float) -> None:
        self.device = device
        self.reset_at = reset_at
        self.last_byte: float | None = None
        self.running = False
        self.bytes_taken = 0

    def _leaves_at(self) -> float:
        if self.last_byte is None:
            return self.reset_at + self.FIRST_WINDOW
        return self.last_byte + self.WAIT_AFTER_BYTE

    def receive_data(self, data: bytes, now: float) -> list[DeviceEvent]:
        if not self.running and now >= self._leaves_at():
            self.running = True
            self.device.reset()
        if self.running:
            return self.device.receive_data(data, now)
        if data and (self.last_byte is not None or now < self.reset_at + self.FIRST_WINDOW):
            self.last_byte = now
            self.bytes_taken += len(data)
        return []

    def data_to_send(self) -> bytes:
        return self.device.data_to_send() if self.running else b""


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
    bootloader = Stk500v2(device, sim.t)
    reset_at = sim.t
    sim.device = bootloader  # type: ignore[assignment]  # the bytes the board's UART sees
    end = sim.t + limit
    while sim.t < end and not (bootloader.running and device.configured and sim.host_of(Connected)):
        sim.step()
    return sim, bootloader, reset_at


def test_a_mega_reset_under_a_host_with_a_start_delay_comes_back() -> None:
    """A host built for a board with a ``start_delay`` (the runtime's spec) leaves a reset board
    the 5 s of silence its stk500v2 bootloader needs after each byte; the default host, asking
    every second, holds it in the bootloader (which is why the delay exists)."""
    host = new_session(SessionContext(REG, False, 0.0, WALL0, start_delay=2.0))
    assert isinstance(host, RosserialHost)
    sim, bootloader, reset_at = _mega_reset(host, limit=30.0)
    assert bootloader.bytes_taken > 0, "the reset board was not probed in its first second"
    assert bootloader.running and sim.host_of(Connected)
    assert sim.t - reset_at < 3.0 + 2 * BOOTLOADER_QUIET
    requests = sim.host.stats.topic_requests
    sim.run(60.0)
    assert sim.host.stats.topic_requests == requests, "a healthy board is not asked again"

    _, stuck, _ = _mega_reset(RosserialHost(REG, now=0.0), limit=60.0)
    assert stuck.bytes_taken > 0 and not stuck.running, (
        "the default host's requests, a second apart, keep the bootloader waiting"
    )
