#!/usr/bin/env python3
"""Soak benchmark: many boards at full rate through one bridge for minutes (issue 25,
item 5). Not a test: it prints figures and checks nothing.

The load micro-ROS users report their agent failing under (eight ESP32s driving it to
200-1000 % CPU after hours): ``--boards`` boards (default 1, then 8, then 32), each with
``--topics`` topics (10) published at ``--rate`` Hz (50) and a service called once a second.
Three kinds of processes, as in real use:

- the *boards*, on ``tcp-listen://`` links (WiFi-style boards the bridge dials). Board ``bNN``
  publishes ``std_msgs/String`` on ``/soak/bNN/tJ``; the first ``--reliable`` topics (2) of each
  board go on the native protocol's reliable stream, the others best effort. Each message
  carries its topic's sequence number and CLOCK_MONOTONIC at publishing in ns (one clock for
  every process on the machine). Each board serves ``/soak/bNN/trigger`` (std_srvs/Trigger).
  With ``--boards-kind firmware`` (the default) each board is its own process: the HwBridge
  Arduino library, the C++ that runs on the Uno, built for the host from
  ``tools/bench/SoakBoard`` (``hwbridge firmware build --board host``, once at the start, into
  a temporary folder), which sleeps in ``poll()`` between its ticks. With ``--boards-kind
  python`` they are this script with ``--emulator``: native-protocol device sessions in
  one :class:`~hwbridge.pump.SessionPump` a board, ``--per-emulator`` boards (4) a process. Both
  kinds answer the same commands on stdin (status, go, stop, quit);
- the *bridge*: ``hwbridge connect --protocol native socket://... ...`` (one URL per board), in
  its own process, measured from ``/proc/PID``: CPU (utime + stime, in cores), RSS, open
  descriptors and threads;
- a *client* (``--client``): a graph node that subscribes to every topic, counts each topic's
  messages, measures latency (arrival minus the stamp) and calls each board's service once a
  second, from a thread per board (a call still running at the next second skips that second's
  call: ``calls_skipped``; ``calls_asked_per_s`` is the board count).

Output, one JSON object per line: a ``soak_sample`` line every ``--sample`` seconds (10) with
the bridge's figures, the emulators' and the client's CPU, the messages and latency of that
interval and the load average; then a ``soak`` summary per board count: ``cpu_cores`` (the
bridge's mean), ``rss_growth_pct`` and ``fds_growth`` from the sample at minute 2 (or at a
fifth of a shorter run) to the last, p50/p99 latency (ms, over the whole run), reliable
messages lost (published by the boards minus received by the client, exact: every message is
numbered) and best-effort ones lost, messages/s received against offered, service calls and
their p50/p99, ``board_session_ends`` (the boards' sessions lost or reset by the peer: a
reset drops what a reliable queue held), ``drain_s`` (after the boards stop, how long until
every reliable message arrived or nothing more came for 5 s), and the acceptance figures
(below one core, RSS growth below 5 %, no reliable message lost). ``peer`` is null:
micro-ROS's agent (the software those reports are about) is not packaged for this machine; the
baseline is this bridge at 1 and 8 boards in the same run.

If the boards saturate the machine (``emulator_cpu_cores``, the board processes' CPU, near the
cores there are, or ``late_ticks`` growing: a board a whole period behind skips to the next
tick instead of bursting), fewer messages are offered than asked; ``offered_per_s`` says how
many. ``reliable_lost_at_start`` counts the reliable messages numbered below the first each
topic delivered (published before the client's subscriptions took effect, or lost at the start
of a run; the part of ``reliable_lost`` not lost in the steady state). ``emulators`` counts the
board processes and ``boards_kind`` says which kind ran;
``bridge_warnings`` counts the bridge's WARNING lines (a session it lost is one) and
``bridge_warnings_first`` shows the first five.

Where a reliable message is lost, a session ended (ending one discards its reliable stream,
PROTOCOL.md 2.10): ``board_session_ends`` says which end ended it (``link_losses``: the board
declared the link lost; ``peer_resets``: the bridge did, or the board followed its new
session). The firmware boards also account for every link loss they declare
(``loss_account``): the time since the board last read a byte from the bridge
(``since_byte_ms``), how long its own loop had not run just before (``loop_gap_ms``: 200 ms or
more and the board itself was starved, ``board_starved``; else the bridge was silent,
``bridge_silent``) and the bytes left unread in its socket; ``board_own_stalls`` counts the
boards' loop gaps above 200 ms and ``board_max_loop_gap_ms`` is the longest. Host builds apply
the stall rule of PROTOCOL.md 2.9 (only 200 ms of a gap in which the board did not run counts
towards the link timeout; the board's ``stats().stalls``), so a board that was descheduled does
not report the bridge silent for its own absence; losses are never hidden, only attributed.
``--log-dir`` keeps the bridges' logs (``bridge-N-0.log``; sharded: ``bridge-NxB-K.log``);
``--bridges N`` shares the boards out over N bridge processes (Zenoh routers joined into one
graph; the figures add up all of them).

What the losses at 32 boards were: before the pump keeper (hwbridge/pump.py), pumps blocked in
graph publishes behind this client sent the boards nothing for over 0.8 s (39 link losses in 10
minutes). After it, sessions the *bridge* ended (``peer_resets``) by its retry limit (PROTOCOL.md
2.4): a board takes back unacknowledged a service request that finds its one transmit buffer
holding a reliable message waiting for the window (2.8), and these boards, publishing whenever
the buffer was free, refilled it before every retransmission, so the call failed at 5 s and the
10th retransmission ended the session with what the board's window held (5 reliable messages,
46 failed calls in 3 minutes). Boards now keep the buffer for the answer to a request taken back
(tests/firmware/test_service_busy_board.py). What remains are link losses declared by running
boards while the whole bridge process sent nothing for 0.84-1.04 s (``loss_account``; many boards
in the same seconds) when other work loads the 2 cores: 70 link losses and 54 reliable messages
in one 10-minute run (load average 13-26), 2 and none in the next (22-61: no bridge-ended
session, 2 failed calls, those the 2 losses abandoned). A session's end discards its reliable
stream (2.10): keeping those needs a protocol change (a stream that survives a resumed session).

Why the boards are firmware by default: 32 boards x 10 topics x 50 Hz is 16,000 messages/s, and
built in Python (the emulators) that saturated this 2-core machine (load about 24). Starved
emulator processes then went silent for longer than the native protocol's 0.8 s link timeout,
the bridge declared 2 link losses, and the session resets dropped 10 reliable messages: the
bench measured its own emulators, not the bridge. Real boards do not starve; the host builds
cost about 0.015 cores a board at 500 messages/s (measured together: 0.1 cores for 8 boards,
0.29 for 32 on a machine loaded by other work).

This file runs the stages; the Python boards are in ``_soak_board.py``, the client in
``_soak_client.py``, the child processes in ``_soak_children.py`` and the summary in
``_soak_summary.py``.
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
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import free_port, hwbridge_command, proc_sample
from _soak_board import board_name, emulator_main
from _soak_children import Child, start_boards
from _soak_client import DOMAIN, client_main
from _soak_summary import stage_summary, wait_drained

SKETCH = Path(__file__).resolve().parent / "SoakBoard"
"""The firmware boards' sketch (host builds of the HwBridge library)."""


def build_board(out: Path) -> Path:
    """Compiles the SoakBoard sketch as a native program in ``out``; returns it."""
    from hwbridge.firmware.build import build_host_sketch

    print(f"soak: building {SKETCH.name} for the host (g++) ...", file=sys.stderr, flush=True)
    started = time.monotonic()
    program = build_host_sketch(SKETCH, out)
    print(
        f"soak: built {program} in {time.monotonic() - started:.1f} s", file=sys.stderr, flush=True
    )
    return program


def cpu_seconds(pid: int) -> float:
    """utime + stime of process ``pid`` (all its threads), in seconds."""
    with Path(f"/proc/{pid}/stat").open(encoding="ascii") as stat:
        fields = stat.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def shard_ranges(boards: int, shards: int) -> list[range]:
    """Board indices split into ``shards`` contiguous groups as even as can be (one bridge
    process each)."""
    shards = max(1, min(shards, boards))
    cuts = [boards * k // shards for k in range(shards + 1)]
    return [range(cuts[k], cuts[k + 1]) for k in range(shards)]


def _bridge_samples(pids: list[int]) -> dict[str, int]:
    """RSS, threads and descriptors of the bridge processes, added up."""
    total = {"rss_kb": 0, "threads": 0, "fds": 0}
    for pid in pids:
        for key, value in proc_sample(pid).items():
            total[key] += value
    return total


_SHARD_CONFIG: dict[str, Any] = {
    "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
}
"""The Zenoh settings of a bridge process other than the first (plus its connect endpoint)."""


def run_stage(args: argparse.Namespace, boards: int, minutes: float, tmp: Path) -> dict[str, Any]:
    """One stage: ``boards`` boards for ``minutes``; prints a ``soak_sample`` line every
    ``--sample`` seconds (unless ``args.quiet_samples``) and returns the stage's summary.
    ``args.bridges`` (1) bridge processes share the boards (contiguous groups; each process is a
    Zenoh router on its own endpoint, the others connected to the first, whose endpoint the
    client connects to: one graph); ``args.calls`` (True): the client
    calls every board's service once a second."""
    shards = getattr(args, "bridges", 1)
    groups = shard_ranges(boards, shards)
    endpoints = [f"tcp/127.0.0.1:{free_port()}" for _ in groups]
    ports = [free_port() for _ in range(boards)]
    emulators: list[Child] = []
    client: Child | None = None
    bridges: list[subprocess.Popen[bytes]] = []
    name = f"bridge-{boards}" if len(groups) == 1 else f"bridge-{boards}x{len(groups)}"
    logs = [(tmp / f"{name}-{k}.log").open("w+") for k in range(len(groups))]
    try:
        start_boards(args, ports, emulators)
        env = dict(os.environ, HWBRIDGE_DOMAIN=DOMAIN)
        env.pop("HWBRIDGE_ENDPOINT", None)
        env.pop("HWBRIDGE_ZENOH_CONFIG", None)
        for shard, (group, endpoint, log) in enumerate(zip(groups, endpoints, logs, strict=True)):
            shard_env = env
            if shard:  # the other bridges' routers join the first's: one graph
                config = tmp / f"{name}-{shard}.json5"
                config.write_text(
                    json.dumps(_SHARD_CONFIG | {"connect": {"endpoints": endpoints[:1]}})
                )
                shard_env = dict(env, HWBRIDGE_ZENOH_CONFIG=str(config))
            command = [*hwbridge_command(), "connect", "--listen", endpoint, "--quiet"]
            command += ["--protocol", "native"]
            for index in group:
                command += ["--name", board_name(index)]
            command += [f"socket://127.0.0.1:{ports[index]}" for index in group]
            bridges.append(
                subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=log, env=shard_env)
            )
        deadline = time.monotonic() + 60 + boards
        while sum(int(e.ask("status")) for e in emulators) < boards:
            if time.monotonic() > deadline or any(b.poll() is not None for b in bridges):
                logs[0].seek(0)
                text = logs[0].read()[-2000:]
                raise RuntimeError(f"{boards} boards did not all connect: {text}")
            time.sleep(0.2)
        client = Child.script("--client", endpoints[0], str(boards), str(args.topics))
        time.sleep(2.0)  # the subscriptions reach the bridge
        if getattr(args, "calls", True):
            client.ask("call")
        bridge_pids = [b.pid for b in bridges]
        client_pid = client.process.pid
        emulator_pids = [e.process.pid for e in emulators]
        for emulator in emulators:
            if emulator.ask("go") != "going":
                raise RuntimeError("an emulator did not start publishing")
        started = time.monotonic()
        last_t = started
        last_bridge = first_cpu = sum(cpu_seconds(pid) for pid in bridge_pids)
        last_client = cpu_seconds(client_pid)
        last_emu = [cpu_seconds(pid) for pid in emulator_pids]
        samples: list[dict[str, Any]] = []
        duration = minutes * 60.0
        while True:
            now = time.monotonic()
            remaining = started + duration - now
            if remaining <= 0:
                break
            time.sleep(min(args.sample, remaining))
            now = time.monotonic()
            dt = now - last_t
            bridge_cpu_s = sum(cpu_seconds(pid) for pid in bridge_pids)
            client_cpu_s = cpu_seconds(client_pid)
            emu = [cpu_seconds(pid) for pid in emulator_pids]
            stats = json.loads(client.ask("stats"))
            sample = {
                "bench": "soak_sample",
                "boards": boards,
                "bridges": len(bridges),
                "t_s": round(now - started, 1),
                "bridge_cpu_cores": round((bridge_cpu_s - last_bridge) / dt, 3),
                **_bridge_samples(bridge_pids),
                "emulator_cpu_cores": round((sum(emu) - sum(last_emu)) / dt, 3),
                "emulator_max_cpu_cores": round(
                    max(b - a for a, b in zip(last_emu, emu, strict=True)) / dt, 3
                ),
                "client_cpu_cores": round((client_cpu_s - last_client) / dt, 3),
                "messages_per_s": round(stats["messages"] / dt, 1),
                "p50_ms": stats["p50_ms"],
                "p99_ms": stats["p99_ms"],
                "calls": stats["calls"],
                "call_p50_ms": stats["call_p50_ms"],
                "loadavg": [round(x, 2) for x in os.getloadavg()],
            }
            samples.append(sample)
            if not getattr(args, "quiet_samples", False):
                sys.stdout.write(json.dumps(sample) + "\n")
                sys.stdout.flush()
            last_t, last_bridge, last_client, last_emu = now, bridge_cpu_s, client_cpu_s, emu
            for bridge in bridges:
                if bridge.poll() is not None:
                    raise RuntimeError(f"a bridge exited ({bridge.returncode})")
        elapsed = time.monotonic() - started
        bridge_cpu = (sum(cpu_seconds(pid) for pid in bridge_pids) - first_cpu) / elapsed
        counts: dict[str, Any] = {}
        late = 0
        for emulator in emulators:
            answer = json.loads(emulator.ask("stop", 30))
            counts.update(answer["boards"])
            late += answer["late_ticks"]
        final, drain_s = wait_drained(client, counts, boards, args.reliable)
        summary = stage_summary(args, boards, minutes, samples, counts, final, bridge_cpu, late)
        summary["bridges"] = len(bridges)
        summary["emulators"] = len(emulators)
        summary["drain_s"] = drain_s
        lines: list[str] = []
        for log in logs:
            log.seek(0)
            lines += log.read().splitlines()
        summary["bridge_errors"] = [line for line in lines if "ERROR" in line][:5]
        warnings = [line for line in lines if "WARNING" in line]
        summary["bridge_warnings"] = len(warnings)
        summary["bridge_warnings_first"] = warnings[:5]
        return summary
    finally:
        if client is not None:
            client.close()
        for bridge in bridges:
            if bridge.poll() is None:
                bridge.send_signal(signal.SIGINT)
        for bridge in bridges:
            try:
                bridge.wait(15)
            except subprocess.TimeoutExpired:
                bridge.kill()
                bridge.wait()
        for emulator in emulators:
            emulator.close()
        for log in logs:
            log.close()


def _floats(text: str) -> list[float]:
    return [float(part) for part in text.split(",") if part]


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--boards", default="1,8,32", help="board counts, one stage each")
    parser.add_argument(
        "--minutes",
        default="1,1,10",
        help="minutes per stage (one value for all, or one per --boards entry)",
    )
    parser.add_argument("--rate", type=float, default=50.0, help="messages/s per topic")
    parser.add_argument("--topics", type=int, default=10, help="topics per board")
    parser.add_argument("--reliable", type=int, default=2, help="reliable topics per board")
    parser.add_argument("--sample", type=float, default=10.0, help="seconds between samples")
    parser.add_argument(
        "--boards-kind",
        choices=("firmware", "python"),
        default="firmware",
        help="boards as host builds of the HwBridge library (one process each), or as Python"
        " emulators (--per-emulator boards a process)",
    )
    parser.add_argument(
        "--per-emulator", type=int, default=4, help="boards per Python emulator process"
    )
    parser.add_argument(
        "--bridges",
        type=int,
        default=1,
        help="bridge processes sharing the boards (contiguous groups, one Zenoh graph)",
    )
    parser.add_argument(
        "--log-dir",
        help="keep the bridge's log (bridge-N.log, one per stage) in this folder",
    )
    parser.add_argument("--emulator", nargs=5, help=argparse.SUPPRESS)
    parser.add_argument("--client", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.emulator:
        first, ports, topics, rate, reliable = args.emulator
        emulator_main(
            int(first), [int(p) for p in ports.split(",")], int(topics), float(rate), int(reliable)
        )
        return
    if args.client:
        client_main(args.client[0], int(args.client[1]), int(args.client[2]))
        return
    counts = [int(b) for b in _floats(args.boards)]
    minutes = _floats(args.minutes)
    if len(minutes) == 1:
        minutes *= len(counts)
    if len(minutes) != len(counts):
        parser.error("--minutes: give one value, or one per --boards entry")
    with tempfile.TemporaryDirectory(prefix="hwbridge-soak-") as tmp:
        args.board_program = None
        if args.boards_kind == "firmware":
            args.board_program = build_board(Path(tmp) / "board")
        logs = Path(args.log_dir) if args.log_dir else Path(tmp)
        logs.mkdir(parents=True, exist_ok=True)
        for boards, stage_minutes in zip(counts, minutes, strict=True):
            summary = run_stage(args, boards, stage_minutes, logs)
            sys.stdout.write(json.dumps(summary) + "\n")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
