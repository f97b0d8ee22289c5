"""Eight emulated boards on one CAN bus, all usable from the CLI at once: the emulator in one
process (``python -m hwbridge.emulator.can_bus``), ``hwbridge connect`` with eight can:// links
in another, CLI tools in more. Once over python-can's udp_multicast bus, once through the
emulated SLCAN adapter on a pty driven by python-can's own ``slcan`` interface."""

from __future__ import annotations

import json
import random
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from tests.bridgeproc import BridgeProcess
from tests.netutil import free_port, stop_child, wait_until

NODES = range(1, 9)


class Emulator:
    def __init__(self, *args: str) -> None:
        self.process = subprocess.Popen(
            [sys.executable, "-m", "hwbridge.emulator.can_bus", "--boards", "8", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.lines.append(line.rstrip("\n"))

    def links(self) -> list[str]:
        assert wait_until(lambda: any(x.startswith("links: ") for x in self.lines), 30), self.lines
        line = next(x for x in self.lines if x.startswith("links: "))
        return line.removeprefix("links: ").split()

    def stop(self) -> None:
        stop_child(self.process, signal.SIGTERM)


@pytest.fixture(params=["udp_multicast", "slcan"])
def emulator(request: pytest.FixtureRequest) -> Iterator[Emulator]:
    common = ["--rate", "1", "--sensor-rate", "0.5"]
    if request.param == "slcan":
        # python-can's slcan reader makes two system calls per byte: keep the bus light.
        process = Emulator("--slcan", "--rate", "1", "--sensor-rate", "0.1")
    else:
        group = f"239.74.{random.randrange(1, 250)}.{random.randrange(1, 250)}"
        # Each board sends at 1/8 of 1 Mbit/s, as eight boards sharing a real bus would: a
        # burst of eight 124-frame Odometry transfers at once would overflow the bridge's UDP
        # receive buffer (frames a CAN bus could never have carried that fast).
        process = Emulator(
            "--bus", f"udp_multicast/{group}", "--port", str(free_port()), "--pace", "125000",
            *common,
        )  # fmt: skip
    yield process
    process.stop()


@pytest.fixture
def bridge(emulator: Emulator, tmp_path: Path) -> Iterator[BridgeProcess]:
    first, *rest = emulator.links()
    assert len(rest) == 7
    assert first.endswith("node1") or "/node1?" in first
    process = BridgeProcess(first, tmp_path, f"can{free_port()}", *rest)
    process.wait_ready()
    yield process
    process.stop()


def _session_ended(bridge: BridgeProcess, stderr: str) -> bool:
    """The command failed because a board's session ended under it (told by the bridge's log)."""
    told = ("no server", "session", "link lost")
    return any(x in stderr for x in told) and "link lost" in bridge.output()


BATCH = 6
"""CLI processes started at once: more would starve the bridge of CPU on a two-core machine
(python-can's slcan reader takes a call per byte), its sessions would time out."""


def _run_all(
    bridge: BridgeProcess, commands: list[list[str]]
) -> list[subprocess.CompletedProcess[str]]:
    """Run CLI commands, BATCH at the same time."""
    results: list[subprocess.CompletedProcess[str] | None] = [None] * len(commands)

    def run(index: int) -> None:
        result = bridge.cli(*commands[index], timeout=90)
        if result.returncode != 0 and _session_ended(bridge, result.stderr):
            # With both cores busy an emulated board (eight in one Python process) can go
            # unheard for its 0.8 s link timeout: the bridge ends that session, fails what was
            # in flight with a message saying so, and negotiates again (a second or so). The
            # call is retried once then; anything else fails the test.
            wait_until(lambda: _listed(bridge), 30)
            result = bridge.cli(*commands[index], timeout=90)
        results[index] = result

    for start in range(0, len(commands), BATCH):
        threads = [
            threading.Thread(target=run, args=(i,))
            for i in range(start, min(start + BATCH, len(commands)))
        ]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    return [r for r in results if r is not None]


def _listed(bridge: BridgeProcess) -> bool:
    names = bridge.cli("service", "list").stdout + bridge.cli("topic", "list").stdout
    return all(f"/node{n}/whoami" in names and f"/node{n}/command" in names for n in NODES)


def test_eight_boards_from_the_cli_at_once(bridge: BridgeProcess, emulator: Emulator) -> None:
    assert wait_until(lambda: _listed(bridge), 60), bridge.output()
    commands: list[list[str]] = [
        ["topic", "echo", "/node3/odom", "-n", "1", "--json", "--timeout", "60"],
        ["topic", "echo", "/node8/imu", "-n", "1", "--json", "--timeout", "60"],
    ]
    for node in NODES:
        # generous: six CLI processes start at once, on a machine that may be busy
        commands.append(["service", "call", f"/node{node}/whoami", "--timeout", "30"])
        commands.append(
            [
                "topic",
                "pub",
                f"/node{node}/command",
                "std_msgs/UInt32",
                f"{{data: {node * 11}}}",
                "-1",
            ]
        )
    results = _run_all(bridge, commands)
    for command, result in zip(commands, results, strict=True):
        warnings = [x for x in bridge.output().splitlines() if "WARNING" in x or "ERROR" in x]
        assert result.returncode == 0, (command, result.stdout, result.stderr, warnings)
    for node in NODES:
        answer = yaml.safe_load(results[2 + 2 * (node - 1)].stdout)
        assert answer == {"success": True, "message": f"node {node}"}

    def missing() -> list[int]:
        return [n for n in NODES if f"node{n} command {n * 11}" not in emulator.lines]

    if not wait_until(lambda: not missing(), 30):
        # A command that reached the bridge as the board's session ended (the link timeout,
        # as in _run_all) went with that session: a reliable message does not outlive its
        # session (PROTOCOL.md 2.10). Published again once the sessions are back.
        for node in missing():
            assert f"node{node}: session ended" in bridge.output(), (node, bridge.output())
            assert wait_until(lambda: _listed(bridge), 30), bridge.output()
            again = bridge.cli(*commands[3 + 2 * (node - 1)], timeout=90)
            assert again.returncode == 0, again.stderr
    assert wait_until(lambda: not missing(), 30), (
        missing(),
        [x for x in emulator.lines if " command " in x],
        bridge.output()[-3000:],
    )
    odom = json.loads(results[0].stdout.splitlines()[0])
    imu = json.loads(results[1].stdout.splitlines()[0])
    assert "node3_base" in json.dumps(odom)
    assert "node8_imu" in json.dumps(imu)
    # the shared bus's own counters reach 'hwbridge board stats'
    stats = bridge.cli("board", "stats", "node5", "--json")
    assert stats.returncode == 0, stats.stderr
    can = json.loads(stats.stdout)["transport"]["can"]
    assert can["frames_in"] > 0 and can["frames_out"] > 0, can
    assert set(can["claims"]) >= {str(n) for n in NODES}, can
