#!/usr/bin/env python3
"""Reset benchmark: what 1,000 board resets leave behind in the bridge (issue 25, item 4).

Two processes per case, as a user has them: the *bridge*, ``hwbridge connect URL`` in its own
process, and a *board* (this script with ``--board``) that resets ``--resets`` times, waiting
after each reset until its new session is up again. Every ``--every`` resets the bridge's
process is measured from ``/proc/PID``: RSS (``VmRSS`` of ``status``, kB), threads (entries of
``task/``) and open descriptors (entries of ``fd/``). The bridge's parameter listeners are
checked by a test instead (tests/hwbridge/test_resets.py): they are not visible from outside.

Cases (``bench``):

- ``resets_native_pty``: an emulated :class:`~hwbridge.emulator.board.VirtualBoard` (the
  packaged ``diffbot``, its devices publishing) on a pty; ``VirtualBoard.reset()`` reboots it
  (a new protocol session with a new session id on the same link, as a board on a USB-serial
  adapter does), and the reset is over when the new session is connected;
- ``resets_rosserial_tcp``: a rosserial sketch (the rosserial client emulation) dialing the
  bridge's ``tcp-listen://`` link, as a WiFi board does; each reset drops the connection and
  dials again with a fresh device (power-on state), over when the device is configured;
- ``resets_rosserial_pty``: a rosserial sketch on a pty whose port goes away at the reset and
  comes back at the same path with a fresh device, as boards with native USB (Leonardo,
  ESP32-S3, RP2040) re-enumerate; over when the device is configured again. The board stays up
  2 s before each reset (a port that closes sooner is a flapping link, reopened with growing
  backoff), so these resets take about 2.3 s each and have their own count, ``--pty-resets``
  (default: ``--resets``). (A reset that keeps
  the port waits out the host's 15 s sync timeout, rosserial's own way of noticing; 1,000 of
  those take four hours, so they are left to tests/hwbridge/test_resets.py.)

One JSON line per sample (``"sample": true``: resets so far, rss_kb, threads, fds, seconds)
and one summary line per case: the first and last samples, and the growth of each figure as
the average over the last ``window`` resets minus the average over the first ``window``
(``window`` = 100, or half the resets if fewer). ``peer`` is ``idle``: the same bridge measured
for as long with its board connected and not resetting, at the end of the run (what the figures
drift by with no resets at all).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import child_line, free_port, hwbridge_command, proc_sample, stop_process

DOMAIN = "resets_bench"
CASES = ("native_pty", "rosserial_tcp", "rosserial_pty")
PTY_HOLD = 2.0
"""Seconds a re-enumerating board stays up before its next reset: a port that closes sooner
after opening counts as a flapping link, which the bridge reopens with growing backoff (up to
10 s, by design: two programs fighting over one board)."""
RESET_TIMEOUT = 30.0
"""Longest wait for a board's session to come back after one reset."""


# ---------------------------------------------------------------------------------- /proc
def cpu_seconds(pid: int) -> float:
    """utime + stime of process ``pid`` (all its threads), in seconds."""
    with Path(f"/proc/{pid}/stat").open(encoding="ascii") as stat:
        fields = stat.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


# ---------------------------------------------------------------------------------- the board
def _wait(condition: Callable[[], bool], timeout: float = RESET_TIMEOUT) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise RuntimeError("the board's session did not come back")
        time.sleep(0.002)


class _NativeBoard:
    """The packaged diffbot's board, emulated on a pty; reset by ``VirtualBoard.reset``."""

    def __init__(self, where: str) -> None:
        from hwbridge.emulator.board import VirtualBoard, load_board
        from hwbridge.links import open_link

        self.board = VirtualBoard(load_board("diffbot"))
        self.board.start(open_link(f"pty://?symlink={where}"))

    def _connected(self) -> bool:
        pump = self.board.pump
        return pump is not None and bool(pump.call(lambda s: s.inner.connected))

    def up(self) -> None:
        _wait(self._connected)

    def reset(self) -> None:
        self.board.reset()
        self.up()

    def close(self) -> None:
        self.board.stop()


class _RosserialBoard:
    """A rosserial sketch that dials ``socket://`` (tcp) or opens a pty (pty) at each power-on:
    a reset ends the connection (closes the port) and starts a fresh device on a new one."""

    def __init__(self, url: str, hold: float = 0.0) -> None:
        self.url = url
        self.hold = hold
        self.link: Any = None
        self.pump: Any = None
        self.count = 0
        self._power_on()

    def _power_on(self) -> None:
        from hwbridge import msg
        from hwbridge.links import open_link
        from hwbridge.protocols.rosserial import RosserialDevice
        from hwbridge.pump import SessionPump

        device = RosserialDevice(msg.registry())
        device.advertise("chatter", "std_msgs/String")
        device.subscribe("led", "std_msgs/Bool")
        answer = msg.encode(msg.new("std_srvs/TriggerResponse", success=True, message="ok"))
        device.advertise_service("trigger", "std_srvs/Trigger", lambda _request: answer)
        deadline = time.monotonic() + RESET_TIMEOUT
        while True:
            try:
                self.link = open_link(self.url)
                break
            except Exception:  # the bridge's listener is reopening: dial again
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.01)
        self.pump = SessionPump(self.link, device, lambda _event: None, name="rosserial-board")
        self.pump.start()

    def up(self) -> None:
        _wait(lambda: bool(self.pump.call(lambda d: d.configured)))
        self.count += 1
        payload = msg_hello(self.count)
        self.pump.call(lambda d: d.publish("chatter", payload))

    def reset(self) -> None:
        time.sleep(self.hold)
        self.close()
        self._power_on()
        self.up()

    def close(self) -> None:
        self.pump.stop()
        self.link.close()


def msg_hello(count: int) -> bytes:
    from hwbridge import msg

    return msg.encode(msg.new("std_msgs/String", data=f"hello {count}"))


def board_main(case: str, where: str) -> None:
    """Board process: power on, then ``reset N`` on stdin resets N times (prints the seconds)."""
    board: _NativeBoard | _RosserialBoard
    print("ready", flush=True)  # the bridge starts now (a WiFi board dials it)
    if case == "native_pty":
        board = _NativeBoard(where)
    elif case == "rosserial_tcp":
        board = _RosserialBoard(f"socket://{where}")
    else:
        board = _RosserialBoard(f"pty://?symlink={where}", hold=PTY_HOLD)
    board.up()
    print("up", flush=True)
    for line in sys.stdin:
        command, _, arg = line.strip().partition(" ")
        if command == "reset":
            started = time.monotonic()
            for _ in range(int(arg)):
                board.reset()
            print(json.dumps(time.monotonic() - started), flush=True)
        elif command == "quit":
            break
    board.close()


# ---------------------------------------------------------------------------------- the harness
def _average(samples: list[dict[str, Any]], key: str) -> float:
    return sum(float(s[key]) for s in samples) / len(samples)


def run_case(case: str, resets: int, every: int, tmp: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    protocol = "native" if case.startswith("native") else "rosserial"
    if case == "rosserial_tcp":
        port = free_port()
        bridge_url = f"tcp-listen://127.0.0.1:{port}?takeover=1"  # a reboot replaces the board
        board_where = f"127.0.0.1:{port}"
    else:
        board_where = str(tmp / f"tty-{case}")
        bridge_url = board_where
    env = dict(os.environ, HWBRIDGE_DOMAIN=DOMAIN)
    env.pop("HWBRIDGE_ENDPOINT", None)
    env.pop("HWBRIDGE_ZENOH_CONFIG", None)
    board = subprocess.Popen(
        [sys.executable, __file__, "--board", case, board_where],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    log = (tmp / f"bridge-{case}.log").open("w+")
    bridge: subprocess.Popen[str] | None = None
    try:
        if child_line(board, f"{case} board") != "ready":
            raise RuntimeError(f"{case}: the board did not start")
        command = [*hwbridge_command(), "connect", "--listen", endpoint, "--quiet"]
        bridge = subprocess.Popen(
            [*command, "--protocol", protocol, "--name", "board", bridge_url],
            stdout=subprocess.DEVNULL,
            stderr=log,
            text=True,
            env=env,
        )
        if child_line(board, f"{case} board") != "up":
            raise RuntimeError(f"{case}: the board never connected")
        time.sleep(1.0)  # the bridge settles (its endpoints declared, first time syncs)
        pid = bridge.pid
        samples: list[dict[str, Any]] = []
        started = time.monotonic()
        cpu0 = cpu_seconds(pid)

        def sample(done: int) -> None:
            line = {
                "bench": f"resets_{case}",
                "sample": True,
                "resets": done,
                **proc_sample(pid),
                "seconds": round(time.monotonic() - started, 2),
            }
            samples.append(line)
            sys.stdout.write(json.dumps(line) + "\n")
            sys.stdout.flush()

        sample(0)
        done = 0
        assert board.stdin is not None
        while done < resets:
            step = min(every, resets - done)
            board.stdin.write(f"reset {step}\n")
            board.stdin.flush()
            child_line(board, f"{case} board", RESET_TIMEOUT * step + 10)
            done += step
            if bridge.poll() is not None:
                raise RuntimeError(f"{case}: the bridge exited ({bridge.returncode})")
            sample(done)
        reset_s = time.monotonic() - started
        cpu = cpu_seconds(pid) - cpu0
        # The peer: the same bridge, its board up and idle, for a tenth as long (1-30 s).
        idle_s = min(max(reset_s / 10, 1.0), 30.0)
        before = proc_sample(pid)
        time.sleep(idle_s)
        after = proc_sample(pid)
        window = max(1, min(100, resets // 2))
        first = [s for s in samples if s["resets"] <= window]
        last = [s for s in samples if s["resets"] >= resets - window]
        growth = {
            key: round(_average(last, key) - _average(first, key), 1)
            for key in ("rss_kb", "threads", "fds")
        }
        log.seek(0)
        errors = [
            line for line in log.read().splitlines() if "ERROR" in line or "Traceback" in line
        ]
        summary = {
            "bench": f"resets_{case}",
            "resets": resets,
            "every": every,
            "window": window,
            "growth": growth,
            "rss_growth_pct": round(100 * growth["rss_kb"] / _average(first, "rss_kb"), 2),
            "first": {key: samples[0][key] for key in ("rss_kb", "threads", "fds")},
            "last": {key: samples[-1][key] for key in ("rss_kb", "threads", "fds")},
            "reset_ms": round(1000 * reset_s / max(resets, 1), 1),
            "bridge_cpu_cores": round(cpu / reset_s, 3) if reset_s > 0 else 0.0,
            "peer": "idle",
            "peer_seconds": round(idle_s, 1),
            "peer_growth": {key: after[key] - before[key] for key in before},
            "bridge_errors": errors[:5],
            "loadavg": [round(x, 2) for x in os.getloadavg()],
        }
        sys.stdout.write(json.dumps(summary) + "\n")
        sys.stdout.flush()
    except RuntimeError:
        log.seek(0)
        sys.stderr.write(f"{case}: the bridge said:\n{log.read()[-3000:]}\n")
        raise
    finally:
        if board.poll() is None and board.stdin is not None:
            try:
                board.stdin.write("quit\n")
                board.stdin.flush()
                board.wait(10)
            except (OSError, subprocess.TimeoutExpired):
                board.kill()
                board.wait()
        if bridge is not None:
            stop_process(bridge, signal.SIGINT)
        log.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--resets", type=int, default=1000, help="resets per case")
    parser.add_argument(
        "--pty-resets", type=int, default=None, help="resets of rosserial_pty (default --resets)"
    )
    parser.add_argument("--every", type=int, default=10, help="resets between samples")
    parser.add_argument("--case", nargs="+", choices=CASES, default=list(CASES))
    parser.add_argument("--board", nargs=2, metavar=("CASE", "WHERE"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.board:
        board_main(*args.board)
        return
    with tempfile.TemporaryDirectory(prefix="hwbridge-resets-") as tmp:
        for case in args.case:
            count = args.resets
            if case == "rosserial_pty" and args.pty_resets is not None:
                count = args.pty_resets
            run_case(case, max(1, count), max(1, args.every), Path(tmp))


if __name__ == "__main__":
    main()
