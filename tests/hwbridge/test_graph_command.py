"""``hwbridge graph`` (a graph with no boards) with ``record``, ``play`` and ``topic`` against it,
and what a second graph owner on a busy endpoint says. Every command is a real process."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.netutil import free_port, wait_until

RUST_PLACE = re.compile(r"\.rs:\d+")
DIFFBOT = str(Path(__file__).resolve().parents[2] / "examples" / "robots" / "diffbot.yaml")


class Proc:
    """``hwbridge ARGS`` running in the background, its stdout and stderr in files."""

    def __init__(self, tmp: Path, name: str, env: dict[str, str], *argv: str) -> None:
        self.out = tmp / f"{name}.out"
        self.err = tmp / f"{name}.err"
        with self.out.open("w") as out, self.err.open("w") as err:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "hwbridge", *argv], env=env, stdout=out, stderr=err
            )

    def stdout(self) -> str:
        return self.out.read_text()

    def stderr(self) -> str:
        return self.err.read_text()

    def interrupt(self) -> int:
        """Ctrl-C, then its exit status."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            return self.process.wait(30)
        finally:
            if self.process.poll() is None:
                self.process.kill()
                self.process.wait()


def run(env: dict[str, str], *argv: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hwbridge", *argv],
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


@pytest.fixture
def env(tmp_path: Path) -> dict[str, str]:
    return {
        **os.environ,
        "HWBRIDGE_ENDPOINT": f"tcp/127.0.0.1:{free_port()}",
        "HWBRIDGE_DOMAIN": f"graphcmd{os.getpid()}",
    }


@pytest.fixture
def graph(tmp_path: Path, env: dict[str, str]) -> Iterator[Proc]:
    """``hwbridge graph`` on the test's endpoint, once its first line (the endpoint) is out."""
    proc = Proc(tmp_path, "graph", env, "graph")
    try:
        assert wait_until(
            lambda: bool(proc.stdout()) or proc.process.poll() is not None, 120, step=0.05
        )
        assert proc.stdout().splitlines()[0] == env["HWBRIDGE_ENDPOINT"], proc.stderr()
        yield proc
    finally:
        assert proc.interrupt() == 0, proc.stderr()


def test_play_without_a_board_into_hwbridge_graph(
    graph: Proc, env: dict[str, str], tmp_path: Path
) -> None:
    """Record a topic pub through ``hwbridge graph``, then play the file and echo it there."""
    recording = tmp_path / "chatter.mcap"
    recorder = Proc(tmp_path, "record", env, "record", "/chatter", "-o", str(recording), "-l", "3")
    publisher = Proc(
        tmp_path, "pub", env, "topic", "pub", "/chatter", "std_msgs/String",
        "{data: from the recording}", "-r", "20", "--wait", "60",
    )  # fmt: skip
    try:
        assert recorder.process.wait(120) == 0, recorder.stderr()
    finally:
        publisher.interrupt()
        recorder.interrupt()
    assert recording.stat().st_size > 0

    echo = Proc(tmp_path, "echo", env, "topic", "echo", "/chatter", "--json", "-n", "2")
    player = Proc(tmp_path, "play", env, "play", str(recording), "--loop", "--wait", "60", "-q")
    try:
        assert echo.process.wait(120) == 0, echo.stderr() + player.stderr()
    finally:
        echo.interrupt()
        assert player.interrupt() == 0, player.stderr()
    messages = [json.loads(line) for line in echo.stdout().splitlines()]
    assert [m["data"] for m in messages] == ["from the recording"] * 2


@pytest.mark.parametrize(
    "argv",
    [["graph"], ["connect", "pty://"], ["up", DIFFBOT, "--link", "base=socket://127.0.0.1:9"]],
    ids=["graph", "connect", "up"],
)
def test_a_second_owner_of_a_busy_endpoint_says_what_to_do(
    graph: Proc, env: dict[str, str], argv: list[str]
) -> None:
    endpoint = env["HWBRIDGE_ENDPOINT"]
    done = run(env, *argv)
    assert done.returncode == 1, done.stderr
    port = int(endpoint.rsplit(":", 1)[1])
    assert done.stderr.splitlines() == [
        f"error: {endpoint} is already in use (another 'hwbridge up', 'connect' or 'graph' is "
        f"running?); stop it, or run this one on another endpoint with "
        f"--listen tcp/127.0.0.1:{port + 1}"
    ]
    assert graph.process.poll() is None  # the first one goes on


def test_no_zenoh_source_places_in_errors(tmp_path: Path, env: dict[str, str]) -> None:
    """Nothing listens at the endpoint; a Zenoh config file that is not JSON5."""
    done = run(env, "topic", "list")
    assert done.returncode == 1
    assert done.stderr.startswith("error: cannot join the graph"), done.stderr
    assert f"nothing answers at {env['HWBRIDGE_ENDPOINT']}" in done.stderr
    assert not RUST_PLACE.search(done.stderr), done.stderr
    bad = tmp_path / "zenoh.json5"
    bad.write_text("{mode: ")
    done = run(env, "--zenoh-config", str(bad), "topic", "list")
    assert done.returncode == 1
    assert done.stderr.startswith(f"error: cannot read Zenoh config {bad}: line 1"), done.stderr
    assert not RUST_PLACE.search(done.stderr), done.stderr
    assert len(done.stderr.splitlines()) == 1
