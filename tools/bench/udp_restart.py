#!/usr/bin/env python3
"""UDP restart benchmark: how soon a UDP board is connected again after the bridge restarts
(issue 28, item 3; the target: within 1 s at p99 over 100 restarts).

The board is ``firmware/HwBridge/examples/UdpNode`` built for the host (``UdpHardware<WiFiUDP>``
over BSD sockets) in its own process; the bridge is the real :class:`~hwbridge.bridge.Bridge`
in this process, on ``udp-listen://127.0.0.1:PORT``, with tests/udp_relay.py between them
(passing everything, except during a crash). A restart stops the bridge's board connection
(socket closed, host session ended), waits a down time drawn from 0..``--max-down`` s (seeded),
and starts a new board connection on the same port; half of the stops are clean (the GOODBYE
reaches the board), half are crashes (the relay passes nothing from the stop on, so the board
learns of it from the new bridge's HELLO or its own link timeout, 0.8 s). A restart's time is
from the new connection's start (its socket bound within it) until the bridge reports the board
connected (READY exchanged and the topic table through).

``peer`` is ``cold_start``: the same board program started while the bridge is up, from the
program's start until the bridge reports it connected (``--cold`` samples), in the same run;
``ratio`` is the restarts' p99 over the cold starts' p50. One JSON line per kind of restart
(``clean``, ``crash``) and one for all of them. Ctrl-C stops it (no line for unfinished work).

    PYTHONPATH=. python tools/bench/udp_restart.py --restarts 100
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from hwbridge.bridge import BoardSpec, Bridge  # noqa: E402
from hwbridge.bridge.board import BoardConnection  # noqa: E402
from hwbridge.firmware.build import LIBRARY_DIR, build_host_sketch  # noqa: E402
from hwbridge.graph import Graph  # noqa: E402
from tests.netutil import free_port  # noqa: E402
from tests.udp_relay import UdpRelay  # noqa: E402

NAME = "udpnode"
DEADLINE_S = 30.0
"""A board not connected this long after a restart counts as hung: the run stops with an error."""


def percentile(values: list[float], q: float) -> float:
    """The q-th percentile (0..100), nearest rank."""
    ordered = sorted(values)
    rank = max(1, min(len(ordered), round(q / 100 * len(ordered) + 0.5)))
    return ordered[rank - 1]


def until_connected(board: BoardConnection, started: float) -> float:
    while board.state != "connected":
        if time.monotonic() - started > DEADLINE_S:
            raise SystemExit(
                f"udp_restart: the board did not come back in {DEADLINE_S} s: {board.info()}"
            )
        time.sleep(0.001)
    return time.monotonic() - started


def start_program(exe: Path, relay: UdpRelay) -> subprocess.Popen[str]:
    env = {**os.environ, "HWBRIDGE_UDP_HOST": f"127.0.0.1:{relay.port}"}
    process = subprocess.Popen([str(exe)], stdout=subprocess.PIPE, text=True, env=env)
    assert process.stdout is not None
    process.stdout.readline()  # "udp port N": its socket is bound
    return process


def stop_program(process: subprocess.Popen[str]) -> None:
    process.send_signal(signal.SIGKILL)
    process.wait(10)
    if process.stdout is not None:
        process.stdout.close()


def line(kind: str, times: list[float], cold: list[float], **extra: Any) -> None:
    p50, p99 = percentile(times, 50), percentile(times, 99)
    cold_p50 = percentile(cold, 50)
    record = {
        "bench": "udp_restart",
        "kind": kind,
        "restarts": len(times),
        "p50_s": round(p50, 4),
        "p99_s": round(p99, 4),
        "max_s": round(max(times), 4),
        "mean_s": round(statistics.fmean(times), 4),
        "target_p99_s": 1.0,
        "peer": "cold_start",
        "peer_p50_s": round(cold_p50, 4),
        "ratio": round(p99 / cold_p50, 3),
        **extra,
    }
    sys.stdout.write(json.dumps(record) + "\n")
    sys.stdout.flush()


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--restarts", type=int, default=100)
    parser.add_argument("--cold", type=int, default=10, help="cold starts measured (the peer)")
    parser.add_argument("--max-down", type=float, default=1.2, help="longest down time, s")
    parser.add_argument("--seed", type=int, default=28)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        sys.stderr.write("udp_restart: building examples/UdpNode for the host\n")
        exe = build_host_sketch(LIBRARY_DIR / "examples" / "UdpNode", Path(tmp))
        graph = Graph.embedded(listen=[], domain=f"udp_restart{os.getpid()}")
        bridge = Bridge(graph)
        port = free_port()
        relay = UdpRelay(("127.0.0.1", port), seed=args.seed)
        spec = BoardSpec(f"udp-listen://127.0.0.1:{port}", name=NAME)
        try:
            board = bridge.add_board(spec)
            cold: list[float] = []
            for i in range(args.cold):
                started = time.monotonic()
                program = start_program(exe, relay)
                cold.append(until_connected(board, started))
                stop_program(program)
                # the bridge notices the board is gone (link timeout) before the next one
                while board.state == "connected":
                    time.sleep(0.01)
                sys.stderr.write(f"\rudp_restart: cold start {i + 1}/{args.cold}")
            sys.stderr.write("\n")
            board.stop()
            del bridge.boards[NAME]
            program = start_program(exe, relay)
            times: dict[str, list[float]] = {"clean": [], "crash": []}
            try:
                board = bridge.add_board(spec)
                until_connected(board, time.monotonic())
                for i in range(args.restarts):
                    kind = "crash" if i % 2 else "clean"
                    relay.blackhole = kind == "crash"
                    board.stop()
                    del bridge.boards[NAME]
                    time.sleep(rng.uniform(0.0, args.max_down))  # the bridge is down
                    relay.blackhole = False
                    started = time.monotonic()
                    board = bridge.add_board(spec)
                    times[kind].append(until_connected(board, started))
                    if program.poll() is not None:
                        raise SystemExit("udp_restart: the board program ended")
                    sys.stderr.write(f"\rudp_restart: restart {i + 1}/{args.restarts}")
                sys.stderr.write("\n")
            finally:
                stop_program(program)
            line("clean", times["clean"], cold)
            line("crash", times["crash"], cold)
            line("all", times["clean"] + times["crash"], cold, max_down_s=args.max_down)
        finally:
            relay.close()
            bridge.stop()
            graph.close()


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:
        sys.exit(130)
