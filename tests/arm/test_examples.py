"""The HwBridge examples built for the ARM boards (STM32F405 and the micro:bit's nRF51822), run
in qemu-system-arm behind a real bridge process, and used from the CLI: topics, services,
parameters, logs, host time, and a board reset (QMP system_reset) recovered by the bridge. A
board that does not reach the graph fails the test."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from hwbridge.firmware.qemu import QemuBoard
from hwbridge.firmware.sim.examples import build_example, build_sketch_for_sim
from tests.bridgeproc import BridgeProcess, new_sessions
from tests.netutil import wait_until

SKETCHES = Path(__file__).with_name("sketches")


@dataclass
class Running:
    board: QemuBoard
    bridge: BridgeProcess


@pytest.fixture
def run_example(
    arm_board: str, tmp_path: Path, request: pytest.FixtureRequest
) -> Iterator[Callable[..., Running]]:
    started: list[Running] = []

    def start(name: str, *defines: str) -> Running:
        sketch = SKETCHES / name
        if sketch.is_dir():
            elf = build_sketch_for_sim(sketch, arm_board, defines=list(defines))
        else:
            elf = build_example(name, arm_board, defines=list(defines))
        board = QemuBoard(elf, arm_board).start()
        bridge = BridgeProcess(board.link_url, tmp_path, request.node.name)
        running = Running(board, bridge)
        started.append(running)
        bridge.wait_ready()
        return running

    yield start
    for running in started:
        running.bridge.stop()
        running.board.close()


def _echo(bridge: BridgeProcess, topic: str) -> str:
    # generous: QEMU, the bridge and the CLI share a 2-core host with whatever else runs
    done = bridge.cli("topic", "echo", topic, "-n", "1", "--timeout", "60", timeout=150)
    assert done.returncode == 0, done.stderr + bridge.output()
    return done.stdout


def test_hello_world_and_reset(run_example: Callable[..., Running]) -> None:
    # on the M4 with the unaligned-access trap on as well (HelloWorld uses no printf: newlib's
    # faults with it; the M0 traps always)
    running = run_example("HelloWorld", "HWBRIDGE_UNALIGN_TRAP=1")
    bridge, board = running.bridge, running.board
    assert "data: hello world!" in _echo(bridge, "/chatter")
    assert "/chatter" in bridge.cli("topic", "list").stdout
    sessions = new_sessions(bridge.output())  # (QEMU held past the link's timeout resumes)
    count_at = _symbol(board.elf, "hwbridge::detail::boot_count")
    boots = board.peek(count_at, 1)[0]
    board.reset()  # the board starts again: a new session, taken by the bridge on its own
    # (taken for the old one resumed, it would never say so)
    assert wait_until(lambda: new_sessions(bridge.output()) > sessions, 60), bridge.output()
    assert "data: hello world!" in _echo(bridge, "/chatter")
    assert board.running
    # The boot count in .noinit RAM went through the reset (the start-up code clears .bss, not
    # it) and counted the new boot: with it in the seed, a board whose clock reads the same at
    # every boot (real hardware; QEMU's clock varies) gets a new session id all the same.
    assert board.peek(count_at, 1)[0] == (boots + 1) & 0xFF


STALL_S = 1.5
"""Seconds QEMU and the bridge stop together in the stall test: past both ends' link timeout
(0.8 s)."""


def test_a_machine_that_stalls_keeps_the_session(run_example: Callable[..., Running]) -> None:
    """QEMU and the bridge stop together for STALL_S, three times (a machine too busy for both:
    CI's was, once). The board's guest clock runs on the host's time, so it jumps on by the
    stall; with PROTOCOL.md 2.9's stall rule (HWBRIDGE_QEMU_CLOCK) neither end takes the time it
    did not run for its peer's silence, and the session goes on. Without the rule the board
    dropped the session after each stall."""
    running = run_example("ServiceServer")
    bridge, board = running.bridge, running.board
    assert wait_until(lambda: "/set_led" in bridge.cli("service", "list").stdout, 30)
    assert board.pid is not None
    processes = [board.pid, bridge.process.pid]
    for _ in range(3):
        try:
            for pid in processes:
                os.kill(pid, signal.SIGSTOP)
            time.sleep(STALL_S)
        finally:
            for pid in reversed(processes):
                os.kill(pid, signal.SIGCONT)
        time.sleep(1.0)  # a link timeout and more for a lost link to show
    done = bridge.cli("service", "call", "/count", "{}", "--timeout", "20")
    assert done.returncode == 0, done.stderr + bridge.output()
    assert "session ended" not in bridge.output(), bridge.output()


def _symbol(elf: Path, name: str) -> int:
    """The address of the symbol ``name`` (demangled) in ``elf``."""
    listed = subprocess.run(
        ["arm-none-eabi-nm", "-C", str(elf)], capture_output=True, text=True, check=True
    ).stdout
    for line in listed.splitlines():
        address, _kind, symbol = line.split(None, 2)
        if symbol == name:
            return int(address, 16)
    raise AssertionError(f"{elf}: no symbol {name}")


def test_service_server(run_example: Callable[..., Running]) -> None:
    running = run_example("ServiceServer")
    bridge, board = running.bridge, running.board
    assert wait_until(lambda: "/set_led" in bridge.cli("service", "list").stdout, 30)
    done = bridge.cli("service", "call", "/set_led", "{data: true}", "--timeout", "20")
    assert done.returncode == 0, done.stderr + bridge.output()
    assert "LED on" in done.stdout
    done = bridge.cli("service", "call", "/count", "{}", "--timeout", "20")
    assert done.returncode == 0, done.stderr
    assert "2 calls" in done.stdout
    # a reset: the board counts from 0 again, and the bridge takes the new session
    board.reset()
    assert wait_until(
        lambda: "1 calls" in bridge.cli("service", "call", "/count", "{}", "--timeout", "5").stdout,
        60,
    ), bridge.output()


def test_parameters_and_logs(run_example: Callable[..., Running]) -> None:
    running = run_example("Parameters")
    bridge, board = running.bridge, running.board
    done = bridge.cli("param", "set", "/gains", json.dumps([1.0, 0.5, 0.01]))
    assert done.returncode == 0, done.stderr
    done = bridge.cli("param", "set", "/blink_period_ms", "100")
    assert done.returncode == 0, done.stderr
    # the value pushed to the board comes back in its log line (floats: 32-bit on the board)
    assert wait_until(lambda: "blink_period_ms = 100" in bridge.output(), 60), bridge.output()
    board.reset()  # the board asks again at its next session
    assert wait_until(lambda: bridge.output().count("blink_period_ms = 100") == 2, 60), (
        bridge.output()
    )
    assert "gains (x1000) = 1000 500 10" in bridge.output()
    done = bridge.cli("param", "set", "/blink_period_ms", "250")
    assert done.returncode == 0, done.stderr
    assert wait_until(lambda: "blink_period_ms = 250" in bridge.output(), 30), bridge.output()


def test_host_time(run_example: Callable[..., Running]) -> None:
    """The board asks the host for its time and keeps it with its own clock: what it publishes
    is the host's time (within a few seconds: the round trips of a loaded host)."""
    running = run_example("ArmTime")
    out = _echo(running.bridge, "/host_time")
    published = float(out.split("data:")[1].split()[0].strip("'\""))
    assert abs(published - time.time()) < 5.0, out
