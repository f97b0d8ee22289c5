"""Shared helpers for the Dynamixel tests: a clock that jumps, an emulated bus on a real pty."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from hwbridge.devices.dynamixel import DynamixelBus, EmulatedBusRunner, emulated_bus
from hwbridge.links import Link, open_link


class JumpClock:
    """Real time plus an offset the test moves forward: the emulated servos live through
    seconds of motion at once, while return delays still pass in real time."""

    def __init__(self) -> None:
        self._offset = 0.0
        self._lock = threading.Lock()

    def __call__(self) -> float:
        with self._lock:
            return time.monotonic() + self._offset

    def jump(self, seconds: float) -> None:
        with self._lock:
            self._offset += seconds


@dataclass
class Bench:
    """A host bus talking to an emulated bus through a real pty."""

    bus: DynamixelBus
    runner: EmulatedBusRunner
    clock: JumpClock
    link: Link

    def settle(self, seconds: float) -> None:
        """Let ``seconds`` of emulated time pass, then one round trip so the bus catches up."""
        self.clock.jump(seconds)
        self.bus.ping(next(iter(s.id for s in self.runner.bus.servos)))


@contextmanager
def serve(name: str, clock: JumpClock | None = None) -> Iterator[EmulatedBusRunner]:
    """Emulated bus ``name`` served on a new ``pty://`` link (open ``runner.slave_path``)."""
    runner = EmulatedBusRunner(emulated_bus(name), clock=clock or JumpClock()).start()
    try:
        yield runner
    finally:
        runner.close()
    assert runner.error is None, runner.error


@contextmanager
def bench(name: str, *, timeout: float = 0.5, retries: int = 0) -> Iterator[Bench]:
    """Emulated bus ``name`` on a pty, and a DynamixelBus on the pty's slave path."""
    clock = JumpClock()
    with serve(name, clock) as runner:
        link = open_link(runner.slave_path)
        try:
            protocol = runner.bus.protocol
            bus = DynamixelBus(link, protocol, timeout=timeout, retries=retries)
            yield Bench(bus, runner, clock, link)
        finally:
            link.close()
