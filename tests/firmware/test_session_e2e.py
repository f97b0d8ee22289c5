"""End to end: a sketch built with ``hwbridge firmware build --board host`` and the real bridge.

``sketches/SessionE2E`` (a reliable counter, a best-effort topic, a subscriber, a service server,
a service client of a graph service this test serves, a blocking and a subscribed parameter,
logs) runs as a native program on a pty; ``hwbridge
connect`` (in its own process) bridges it, and the CLI sees its topics, services, parameters and
logs. Between the two sits a relay of two pseudo-terminals that can lose and corrupt bytes
(seeded, per byte, as the emulator's ``LinkFaults``): killing and restarting the program
recovers without touching the bridge, and on a lossy link the reliable counter still arrives
exactly once and in order.
"""

from __future__ import annotations

import json
import random
import shutil
import signal
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from hwbridge.errors import LinkError
from hwbridge.links import open_link
from hwbridge.links.base import Link
from tests.bridgeproc import BridgeProcess, new_sessions
from tests.netutil import free_port, wait_until

SKETCH = Path(__file__).parent / "sketches" / "SessionE2E"

pytestmark = pytest.mark.skipif(
    shutil.which("g++") is None, reason="g++ is not installed (Debian package g++)"
)


class LossyRelay:
    """Two pseudo-terminals joined by two threads: the bridge opens ``path`` (a symlink to one
    slave), the board program opens :attr:`board_path` (the other). Each byte is lost with
    probability ``loss`` and has one bit flipped with probability ``corrupt``."""

    def __init__(self, path: Path, seed: int = 1) -> None:
        self.bridge_side = open_link(f"pty://?symlink={path}")
        self.board_side = open_link("pty://")
        slave = getattr(self.board_side, "slave_path", None)
        assert isinstance(slave, str)
        self.board_path = slave
        self.loss = 0.0
        self.corrupt = 0.0
        self.damaged = 0
        self._rng = random.Random(seed)
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self._copy, args=(a, b), daemon=True)
            for a, b in ((self.bridge_side, self.board_side), (self.board_side, self.bridge_side))
        ]
        for thread in self._threads:
            thread.start()

    def _damage(self, data: bytes) -> bytes:
        if self.loss == 0.0 and self.corrupt == 0.0:
            return data
        out = bytearray()
        for byte in data:
            roll = self._rng.random()
            if roll < self.loss:
                self.damaged += 1
            elif roll < self.loss + self.corrupt:
                self.damaged += 1
                out.append(byte ^ (1 << self._rng.randrange(8)))
            else:
                out.append(byte)
        return bytes(out)

    def _copy(self, source: Link, sink: Link) -> None:
        while not self._stop.is_set():
            try:
                data = source.read(4096, 0.05)
                if data:
                    sink.write(self._damage(data))
            except LinkError:
                if self._stop.wait(0.05):
                    return

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(2)
        self.bridge_side.close()
        self.board_side.close()


class BoardProgram:
    """The sketch's native program on ``path``; its first line is checked."""

    def __init__(self, exe: Path, path: str) -> None:
        self.process = subprocess.Popen(
            [str(exe), path], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        assert self.process.stdout is not None
        self.first_line = self.process.stdout.readline().strip()

    def kill(self) -> None:
        self.process.send_signal(signal.SIGKILL)
        self.process.wait(10)
        if self.process.stdout is not None:
            self.process.stdout.close()


@pytest.fixture(scope="module")
def program(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from hwbridge.firmware.build import build_host_sketch

    return build_host_sketch(SKETCH, tmp_path_factory.mktemp("e2e_build"))


@pytest.fixture
def relay(tmp_path: Path) -> Iterator[LossyRelay]:
    r = LossyRelay(tmp_path / "ttyBOARD")
    yield r
    r.close()


@pytest.fixture
def bridge(relay: LossyRelay, tmp_path: Path) -> Iterator[BridgeProcess]:
    process = BridgeProcess(tmp_path / "ttyBOARD", tmp_path, f"fw{free_port()}", "--name", "uno")
    process.wait_ready()
    yield process
    process.stop()


def _counts(echo: subprocess.CompletedProcess[str]) -> list[int]:
    docs = [yaml.safe_load(d) for d in echo.stdout.split("---") if d.strip()]
    return [int(d["data"]) for d in docs]


def _board_calls_the_graph(bridge: BridgeProcess) -> None:
    """The board's ServiceClient calls ``/check``, served here on the bridge's graph: an answer
    (kCallOk, 0), then a server that fails (kCallError, 1), then no server at all (the bridge's
    graph call fails: kCallError again)."""
    from hwbridge.graph import Graph

    calls: list[object] = []

    def checked(request: object) -> dict[str, object]:
        calls.append(request)
        if len(calls) > 1:
            raise RuntimeError("check failed on purpose")
        return {"success": True, "message": f"checked {len(calls)}"}

    def ask(expected: str) -> None:
        before = bridge.output().count("asked:")
        pub = bridge.cli("topic", "pub", "/cmd", "std_msgs/String", "{data: ask}")
        assert pub.returncode == 0, pub.stderr
        assert wait_until(lambda: bridge.output().count("asked:") > before, 15), bridge.output()
        said = bridge.output().split("asked:")[-1].splitlines()[0]
        assert expected in said, said

    domain = bridge.env["HWBRIDGE_DOMAIN"]
    with Graph.attached(connect=[bridge.endpoint], domain=domain) as graph:
        server = graph.node("checker").service("/check", "std_srvs/Trigger", checked)
        ask("status 0, success 'checked 1'")
        ask("status 1, no success")
        server.close()
    ask("status 1, no success")  # no server on the graph: the bridge's call fails, an ERROR
    assert len(calls) == 2


def test_host_sketch_through_the_bridge(
    program: Path, relay: LossyRelay, bridge: BridgeProcess
) -> None:
    assert bridge.cli("param", "set", "/rate", "7").returncode == 0
    board = BoardProgram(program, relay.board_path)
    try:
        assert board.first_line == relay.board_path
        assert wait_until(lambda: "board 'e2e' connected" in bridge.output(), 20), bridge.output()

        echo = bridge.cli("topic", "echo", "/counter", "-n", "5", "--timeout", "20")
        assert echo.returncode == 0, echo.stderr + bridge.output()
        counts = _counts(echo)
        assert counts == list(range(counts[0], counts[0] + 5))
        hi = bridge.cli("topic", "echo", "/chatter", "-n", "1", "--timeout", "20")
        assert yaml.safe_load(hi.stdout.split("---")[0]) == {"data": "hi"}

        call = bridge.cli("service", "call", "/ping")
        assert call.returncode == 0, call.stderr
        assert yaml.safe_load(call.stdout) == {"success": True, "message": "pong 1"}

        assert wait_until(lambda: "rate is 7" in bridge.output(), 10), bridge.output()
        pub = bridge.cli("topic", "pub", "/cmd", "std_msgs/String", "{data: hey}")
        assert pub.returncode == 0, pub.stderr
        assert wait_until(lambda: "got hey" in bridge.output(), 10), bridge.output()
        assert bridge.cli("param", "set", "/gain", "5").returncode == 0
        assert wait_until(lambda: "gain now 5" in bridge.output(), 10), bridge.output()
        _board_calls_the_graph(bridge)

        # kill and restart the board program: the bridge reconnects on its own
        board.kill()
        board = BoardProgram(program, relay.board_path)
        assert wait_until(lambda: new_sessions(bridge.output(), "e2e") >= 2, 20), bridge.output()
        call = bridge.cli("service", "call", "/ping")
        assert yaml.safe_load(call.stdout) == {"success": True, "message": "pong 1"}
        assert wait_until(lambda: bridge.output().count("rate is 7") >= 2, 10)

        # a lossy link: the reliable counter still arrives exactly once, in order
        relay.loss, relay.corrupt = 0.002, 0.001
        echo = bridge.cli("topic", "echo", "/counter", "-n", "150", "--timeout", "40")
        assert echo.returncode == 0, echo.stderr + bridge.output()
        counts = _counts(echo)
        assert counts == list(range(counts[0], counts[0] + 150)), counts
        stats = bridge.cli("board", "stats", "uno", "--json")
        assert stats.returncode == 0, stats.stderr
        host = json.loads(stats.stdout)["stats"]
        # the loss was real: bytes were damaged, and the host saw bad frames, gaps, duplicates
        # (frames the board resent) or resent frames itself
        damage = ("crc_errors", "bad_frames", "be_frames_lost", "duplicates", "retransmits")
        assert relay.damaged > 0 and sum(host[k] for k in damage) > 0, host
        # no new session either (a busy machine may hold the board silent past the link's
        # timeout: the session then resumes, '(native, session resumed)', and loses nothing)
        assert new_sessions(bridge.output(), "e2e") == 2, bridge.output()
    finally:
        board.kill()
