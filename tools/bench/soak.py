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
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import child_line, free_port, hwbridge_command, proc_sample

DOMAIN = "soak_bench"
BIN_S = 1e-4
"""Latency histogram resolution (0.1 ms)."""
BINS = 30_000
"""Histogram bins (up to 3 s; later arrivals count in the last bin)."""
WARM_S = 120.0
"""RSS and descriptor growth are taken from this far into a run (or a fifth of a shorter run)."""


def board_name(index: int) -> str:
    return f"b{index:02d}"


def topic_name(index: int, topic: int) -> str:
    return f"/soak/{board_name(index)}/t{topic}"


# ---------------------------------------------------------------------------------- emulators
class _Board:
    """One native board: a device session in a pump on a tcp-listen link."""

    def __init__(self, index: int, port: int, topics: int, reliable: int) -> None:
        from hwbridge import msg
        from hwbridge.links import open_link
        from hwbridge.protocols.native import session as ns
        from hwbridge.protocols.native.control import EntryKind
        from hwbridge.pump import SessionPump

        registry = msg.registry()
        string_md5 = registry.md5("std_msgs/String")
        entries = [
            ns.TopicEntry(
                1 + j,
                EntryKind.PUBLISHER,
                topic_name(index, j)[1:],
                "std_msgs/String",
                string_md5,
                reliable=j < reliable,
            )
            for j in range(topics)
        ]
        self.service_channel = topics + 1
        entries.append(
            ns.TopicEntry(
                self.service_channel,
                EntryKind.SERVICE_SERVER,
                f"soak/{board_name(index)}/trigger",
                "std_srvs/Trigger",
                registry.service("std_srvs/Trigger").md5,
            )
        )
        self.answer = msg.encode(msg.new("std_srvs/TriggerResponse", success=True, message="ok"))
        session = ns.DeviceSession(
            ns.BoardInfo(board_name(index), index.to_bytes(4, "little"), "soak"), entries
        )
        self.topics = topics
        self.seq = [0] * topics
        self.published = [0] * topics
        self.refused = [0] * topics
        self.served = 0
        self.link = open_link(f"tcp-listen://127.0.0.1:{port}")
        self.pump = SessionPump(self.link, session, self._on_event, name=board_name(index))
        self.pump.start()

    def _on_event(self, event: Any) -> None:
        from hwbridge.protocols.native import session as ns

        if isinstance(event, ns.ServiceRequest):
            self.served += 1
            answer = self.answer
            self.pump.call(lambda s: s.respond_service(event.channel, event.request_id, answer))

    def connected(self) -> bool:
        return bool(self.pump.call(lambda s: s.connected))

    def session_ends(self) -> dict[str, int]:
        """How often this board's session ended and started again (a reset loses what its
        reliable queue held): link losses, peer resets, sessions established."""
        stats = self.pump.call(lambda s: s.stats)
        return {
            "link_losses": int(stats.link_losses),
            "peer_resets": int(stats.peer_resets),
            "sessions": int(stats.sessions),
        }

    def publish_all(self, session: Any) -> None:
        """Under the pump's lock: one message on each topic."""
        seq, published, refused = self.seq, self.published, self.refused
        for j in range(self.topics):
            data = f"{seq[j]} {time.monotonic_ns()}".encode()
            payload = len(data).to_bytes(4, "little") + data
            if session.publish(1 + j, payload):
                published[j] += 1
                seq[j] += 1
            else:
                refused[j] += 1

    def close(self) -> None:
        self.pump.stop()
        self.link.close()


def emulator_main(first: int, ports: list[int], topics: int, rate: float, reliable: int) -> None:
    """Emulator process: boards listening on ``ports``; commands on stdin (status, go, stop)."""
    boards = [_Board(first + i, port, topics, reliable) for i, port in enumerate(ports)]
    running = threading.Event()
    finished = threading.Event()
    late = [0]

    def publisher() -> None:
        period = 1.0 / rate
        running.wait()
        next_tick = time.monotonic()
        while running.is_set():
            for board in boards:
                try:
                    board.pump.call(board.publish_all)
                except Exception:  # noqa: BLE001 - a board whose link dropped: count as refused
                    for j in range(topics):
                        board.refused[j] += 1
            next_tick += period
            delay = next_tick - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -period:  # a whole period behind: the process cannot keep the rate
                late[0] += 1
                next_tick = time.monotonic()
        finished.set()

    thread = threading.Thread(target=publisher, daemon=True)
    thread.start()
    print("ready", flush=True)
    for line in sys.stdin:
        command = line.strip()
        if command == "status":
            print(json.dumps(sum(board.connected() for board in boards)), flush=True)
        elif command == "go":
            running.set()
            print("going", flush=True)
        elif command == "stop":
            running.clear()
            finished.wait(10)
            counts = {
                board_name(first + i): {
                    "published": board.published,
                    "refused": board.refused,
                    "served": board.served,
                    **board.session_ends(),
                }
                for i, board in enumerate(boards)
            }
            print(json.dumps({"boards": counts, "late_ticks": late[0]}), flush=True)
        elif command == "quit":
            break
    for board in boards:
        board.close()


# ---------------------------------------------------------------------------------- the client
class _Histogram:
    def __init__(self) -> None:
        self.bins = [0] * BINS
        self.count = 0

    def clear(self) -> None:
        self.bins = [0] * BINS
        self.count = 0

    def add(self, seconds: float) -> None:
        index = int(seconds / BIN_S)
        self.bins[min(max(index, 0), BINS - 1)] += 1
        self.count += 1

    def percentile(self, fraction: float) -> float | None:
        """The ``fraction`` percentile in ms (upper edge of its bin), None if empty."""
        if not self.count:
            return None
        target = fraction * self.count
        seen = 0
        for index, count in enumerate(self.bins):
            seen += count
            if seen >= target:
                return round((index + 1) * BIN_S * 1000, 2)
        return round(BINS * BIN_S * 1000, 2)


def client_main(endpoint: str, boards: int, topics: int) -> None:
    """Client process (``endpoint``: the bridges' Zenoh endpoints, comma-separated): subscribe
    to every topic, call every service each second (once told ``call``); commands on stdin:
    ``stats`` (this interval's figures), ``final`` (every topic's counts)."""
    from hwbridge.graph import ANY_TYPE, Graph

    lock = threading.Lock()
    received: dict[str, int] = {}
    out_of_order: dict[str, int] = {}
    last_seq: dict[str, int] = {}
    first_seq: dict[str, int] = {}
    window, total = _Histogram(), _Histogram()
    calls, call_total = _Histogram(), _Histogram()
    failed = [0]
    skipped = [0]
    clock = time.monotonic_ns

    def on_message(message: Any) -> None:
        arrived = clock()
        data: bytes = message.data
        seq_text, _, stamp_text = data[4:].partition(b" ")
        seq = int(seq_text)
        latency = (arrived - int(stamp_text)) * 1e-9
        topic = message.topic
        with lock:
            received[topic] = received.get(topic, 0) + 1
            if seq <= last_seq.get(topic, -1):
                out_of_order[topic] = out_of_order.get(topic, 0) + 1
            else:
                last_seq[topic] = seq
            first_seq.setdefault(topic, seq)
            window.add(latency)
            total.add(latency)

    stop = threading.Event()

    with Graph.attached(connect=endpoint.split(","), domain=DOMAIN) as graph:
        node = graph.node("soak_client")
        for index in range(boards):
            for j in range(topics):
                node.subscriber(topic_name(index, j), ANY_TYPE, on_message, raw=True)

        def caller(index: int) -> None:
            """Board ``index``'s service once a second (a call still running at the next
            second: that second's call is skipped, and counted)."""
            service = f"/soak/{board_name(index)}/trigger"
            next_round = time.monotonic() + index / max(boards, 1)  # spread over the second
            while not stop.wait(max(0.0, next_round - time.monotonic())):
                started = time.monotonic()
                try:
                    node.call_raw(service, "std_srvs/Trigger", b"", 5.0)
                except Exception:  # noqa: BLE001 - counted: a call that failed
                    with lock:
                        failed[0] += 1
                else:
                    elapsed = time.monotonic() - started
                    with lock:
                        calls.add(elapsed)
                        call_total.add(elapsed)
                next_round += 1.0
                behind = int((time.monotonic() - next_round) // 1.0) + 1
                if behind > 0:
                    with lock:
                        skipped[0] += behind
                    next_round += behind

        print("ready", flush=True)
        calling: list[threading.Thread] = []
        for line in sys.stdin:
            command = line.strip()
            if command == "call":
                calling = [
                    threading.Thread(target=caller, args=(index,), daemon=True)
                    for index in range(boards)
                ]
                for thread in calling:
                    thread.start()
                print("calling", flush=True)
            elif command == "stats":
                with lock:
                    stats = {
                        "messages": window.count,
                        "p50_ms": window.percentile(0.5),
                        "p99_ms": window.percentile(0.99),
                        "calls": calls.count,
                        "call_p50_ms": calls.percentile(0.5),
                        "calls_failed": failed[0],
                    }
                    window.clear()
                    calls.clear()
                print(json.dumps(stats), flush=True)
            elif command == "final":
                stop.set()
                for thread in calling:
                    thread.join(10)
                with lock:
                    final = {
                        "received": received,
                        "out_of_order": out_of_order,
                        "first_seq": first_seq,
                        "messages": total.count,
                        "p50_ms": total.percentile(0.5),
                        "p99_ms": total.percentile(0.99),
                        "max_ms": _max_ms(total),
                        "calls": call_total.count,
                        "call_p50_ms": call_total.percentile(0.5),
                        "call_p99_ms": call_total.percentile(0.99),
                        "calls_failed": failed[0],
                        "calls_skipped": skipped[0],
                    }
                print(json.dumps(final), flush=True)
            elif command == "quit":
                break


def _max_ms(histogram: _Histogram) -> float | None:
    for index in range(BINS - 1, -1, -1):
        if histogram.bins[index]:
            return round((index + 1) * BIN_S * 1000, 2)
    return None


# ---------------------------------------------------------------------------------- the harness
class _Child:
    """A child process (this script in another role, or a board program) that answers one
    line per command; ``preamble`` lines it prints before ``ready`` are skipped."""

    def __init__(
        self,
        name: str,
        command: list[str],
        env: dict[str, str] | None = None,
        preamble: int = 0,
    ) -> None:
        self.process = subprocess.Popen(
            command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env
        )
        self.name = name
        for _ in range(preamble):
            self.line()
        self.expect("ready")

    @classmethod
    def script(cls, *args: str) -> _Child:
        """This script with ``args`` (``--emulator ...`` or ``--client ...``)."""
        return cls(args[0], [sys.executable, __file__, *args])

    def line(self, timeout: float = 60.0) -> str:
        return child_line(self.process, self.name, timeout)

    def expect(self, word: str) -> None:
        line = self.line()
        if line != word:
            raise RuntimeError(f"{self.name}: expected {word!r}, got {line!r}")

    def ask(self, command: str, timeout: float = 60.0) -> str:
        stdin = self.process.stdin
        assert stdin is not None
        stdin.write(command + "\n")
        stdin.flush()
        return self.line(timeout)

    def close(self) -> None:
        if self.process.poll() is None:
            try:
                assert self.process.stdin is not None
                self.process.stdin.write("quit\n")
                self.process.stdin.flush()
                self.process.wait(10)
            except (OSError, subprocess.TimeoutExpired):
                self.process.kill()
                self.process.wait()


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


def start_boards(args: argparse.Namespace, ports: list[int], into: list[_Child]) -> None:
    """Starts the board processes into ``into`` (so that the caller stops those started if a
    later one fails): one firmware program per board (``--boards-kind firmware``), or Python
    emulators of ``--per-emulator`` boards each."""
    if args.boards_kind == "firmware":
        assert args.board_program is not None
        for index, port in enumerate(ports):
            into.append(
                _Child(
                    board_name(index),
                    [str(args.board_program), f"listen://127.0.0.1:{port}"],
                    env=dict(
                        os.environ,
                        SOAK_INDEX=str(index),
                        SOAK_TOPICS=str(args.topics),
                        SOAK_RELIABLE=str(args.reliable),
                        SOAK_RATE=str(args.rate),
                    ),
                    preamble=1,  # the link it serves
                )
            )
        return
    per = max(1, args.per_emulator)
    for first in range(0, len(ports), per):
        into.append(
            _Child.script(
                "--emulator",
                str(first),
                ",".join(map(str, ports[first : first + per])),
                str(args.topics),
                str(args.rate),
                str(args.reliable),
            )
        )


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
    emulators: list[_Child] = []
    client: _Child | None = None
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
        client = _Child.script("--client", endpoints[0], str(boards), str(args.topics))
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
        final, drain_s = _drained(client, counts, boards, args.reliable)
        summary = _summary(args, boards, minutes, samples, counts, final, bridge_cpu, late)
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


DRAIN_IDLE_S = 5.0
"""After the boards stop: the client's counts are final once none has grown for this long."""
DRAIN_MAX_S = 120.0


def _drained(
    client: _Child, counts: dict[str, Any], boards: int, reliable: int
) -> tuple[dict[str, Any], float]:
    """The client's final counts once what was in flight has arrived: every reliable message
    the boards published, or nothing more for DRAIN_IDLE_S (a loaded machine may hold seconds of
    backlog in the bridge's reliable windows and queues); and how long that took."""
    wanted = {
        topic_name(index, j): counts[board_name(index)]["published"][j]
        for index in range(boards)
        for j in range(reliable)
    }
    started = last_growth = time.monotonic()
    last_total = -1
    while True:
        final: dict[str, Any] = json.loads(client.ask("final", 30))
        received: dict[str, int] = final["received"]
        now = time.monotonic()
        if all(received.get(topic, 0) >= sent for topic, sent in wanted.items()):
            break
        total = sum(received.values())
        if total != last_total:
            last_total, last_growth = total, now
        if now - last_growth >= DRAIN_IDLE_S or now - started >= DRAIN_MAX_S:
            break
        time.sleep(0.5)
    return final, round(time.monotonic() - started, 1)


def _summary(
    args: argparse.Namespace,
    boards: int,
    minutes: float,
    samples: list[dict[str, Any]],
    counts: dict[str, Any],
    final: dict[str, Any],
    bridge_cpu: float,
    late: int,
) -> dict[str, Any]:
    received: dict[str, int] = final["received"]
    first_seq: dict[str, int] = final["first_seq"]
    reliable_lost = best_effort_lost = published = refused = reliable_lost_at_start = 0
    for index in range(boards):
        board = counts[board_name(index)]
        for j in range(args.topics):
            sent: int = board["published"][j]
            lost = sent - received.get(topic_name(index, j), 0)
            published += sent
            refused += board["refused"][j]
            if j < args.reliable:
                reliable_lost += lost
                reliable_lost_at_start += first_seq.get(topic_name(index, j), sent)
            else:
                best_effort_lost += lost
    duration = minutes * 60.0
    warm = min(WARM_S, duration / 5)
    warm_samples = [s for s in samples if s["t_s"] >= warm] or samples
    start, end = warm_samples[0], samples[-1]
    rss_growth = 100.0 * (end["rss_kb"] - start["rss_kb"]) / start["rss_kb"]
    return {
        "bench": "soak",
        "boards": boards,
        "topics": args.topics,
        "reliable_topics": args.reliable,
        "rate_hz": args.rate,
        "minutes": minutes,
        "cpu_cores": round(bridge_cpu, 3),
        "cpu_cores_max_sample": max(s["bridge_cpu_cores"] for s in samples),
        "rss_kb_start": start["rss_kb"],
        "rss_kb_end": end["rss_kb"],
        "rss_growth_pct": round(rss_growth, 2),
        "rss_from_s": start["t_s"],
        "fds_start": start["fds"],
        "fds_growth": end["fds"] - start["fds"],
        "threads_end": end["threads"],
        "p50_ms": final["p50_ms"],
        "p99_ms": final["p99_ms"],
        "max_ms": final["max_ms"],
        "reliable_lost": reliable_lost,
        "reliable_lost_at_start": reliable_lost_at_start,
        "best_effort_lost": best_effort_lost,
        "board_session_ends": {
            key: sum(counts[board_name(index)][key] for index in range(boards))
            for key in ("link_losses", "peer_resets")
        },
        **_loss_account(counts, boards),
        "out_of_order": sum(final["out_of_order"].values()),
        "published": published,
        "refused_by_board": refused,
        "messages_per_s": round(final["messages"] / duration, 1),
        "asked_per_s": boards * args.topics * args.rate,
        "offered_per_s": round(published / duration, 1),
        "late_ticks": late,
        "calls": final["calls"],
        "calls_failed": final["calls_failed"],
        "calls_skipped": final["calls_skipped"],
        "calls_asked_per_s": float(boards) if getattr(args, "calls", True) else 0.0,
        "call_p50_ms": final["call_p50_ms"],
        "call_p99_ms": final["call_p99_ms"],
        "emulator_cpu_cores": round(
            sum(s["emulator_cpu_cores"] for s in samples) / len(samples), 3
        ),
        "client_cpu_cores": round(sum(s["client_cpu_cores"] for s in samples) / len(samples), 3),
        "boards_kind": args.boards_kind,
        "emulators": 0,
        "cpus": os.cpu_count(),
        "loadavg": [round(x, 2) for x in os.getloadavg()],
        "peer": None,
        "acceptance": {
            "below_one_core": bridge_cpu < 1.0,
            "rss_growth_below_5_pct": rss_growth < 5.0,
            "no_reliable_lost": reliable_lost == 0,
        },
    }


def _loss_account(counts: dict[str, Any], boards: int) -> dict[str, Any]:
    """What the firmware boards say of the link losses they declared (the Python emulators say
    nothing of this): each loss's gap since the board last read a byte from the bridge, how long
    the board's own loop had not run just before (starved of the CPU), and the bytes left unread
    in its socket; the boards' own stalls (loop gaps above 200 ms) and the longest gap."""
    notes: list[dict[str, int]] = []
    stalls = longest = 0
    for index in range(boards):
        board = counts[board_name(index)]
        notes += board.get("losses", [])
        stalls += board.get("own_stalls", 0)
        longest = max(longest, board.get("max_loop_gap_ms", 0))
    starved = [n for n in notes if n["loop_gap_ms"] >= 200]
    return {
        "board_own_stalls": stalls,
        "board_max_loop_gap_ms": longest,
        "loss_account": {
            "noted": len(notes),
            "board_starved": len(starved),
            "bridge_silent": len(notes) - len(starved),
            "since_byte_ms": sorted(n["since_byte_ms"] for n in notes)[-10:],
            "loop_gap_ms": sorted(n["loop_gap_ms"] for n in notes)[-10:],
            "pending_bytes": sorted(n["pending"] for n in notes)[-10:],
        },
    }


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
