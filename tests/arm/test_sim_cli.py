"""``hwbridge firmware sim EXAMPLE --mcu nrf51822|stm32f405``: the URL of the UART's pty is the
first line, the board speaks on it (its HELLO frames), and Ctrl-C stops the command and QEMU
with it (the pty goes away)."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import termios
import time
import tty
from pathlib import Path

import pytest

from hwbridge.firmware.sim.examples import build_example
from tests.arm.conftest import need_arm_tools
from tests.netutil import wait_until


@pytest.mark.parametrize("mcu", ["nrf51822", "stm32f405"])
def test_sim_prints_the_url_first_and_stops_on_ctrl_c(mcu: str) -> None:
    need_arm_tools()
    build_example("HelloWorld", "microbit" if mcu == "nrf51822" else mcu)  # built before the clock
    process = subprocess.Popen(
        [sys.executable, "-m", "hwbridge", "firmware", "sim", "HelloWorld", "--mcu", mcu],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout is not None and process.stderr is not None
        first = process.stdout.readline().strip()
        assert first.startswith("serial:///dev/pts/"), first + process.stderr.read()
        pty = first.removeprefix("serial://")
        fd = os.open(pty, os.O_RDWR | os.O_NOCTTY)
        try:
            tty.setraw(fd, termios.TCSANOW)
            received = b""
            deadline = time.monotonic() + 30
            # a HELLO frame: COBS-encoded, ended by the zero delimiter, more than a few bytes
            while received.count(b"\x00") < 2 and time.monotonic() < deadline:
                ready, _, _ = select.select([fd], [], [], 0.2)
                if ready:
                    received += os.read(fd, 256)
            assert received.count(b"\x00") >= 2, received
        finally:
            os.close(fd)
        process.send_signal(signal.SIGINT)
        assert process.wait(30) == 0, process.stderr.read() if process.stderr else ""
        assert wait_until(lambda: not Path(pty).exists() or _nobody_has(pty), 10)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


def _nobody_has(pty: str) -> bool:
    """No process of ours holds the pty (QEMU is gone; a new one may have the number)."""
    try:
        fd = os.open(pty, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError:
        return True
    os.close(fd)
    return False


def test_a_killed_sim_takes_qemu_with_it() -> None:
    """SIGKILL (no clean-up runs in hwbridge): QEMU goes too, instead of holding its pty."""
    need_arm_tools()
    build_example("HelloWorld", "microbit")
    process = subprocess.Popen(
        [sys.executable, "-m", "hwbridge", "firmware", "sim", "HelloWorld", "--mcu", "nrf51822"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    children: list[int] = []
    try:
        assert process.stdout is not None
        first = process.stdout.readline().strip()
        assert first.startswith("serial:///dev/pts/"), first
        children = [
            int(pid)
            for pid in Path(f"/proc/{process.pid}/task/{process.pid}/children").read_text().split()
        ]
        assert children, "QEMU is not a child of the command"
    finally:
        process.kill()
        process.wait()
    assert wait_until(lambda: not any(_running(pid) for pid in children), 10), children


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"  # a zombie has ended (nobody waited for it yet)
