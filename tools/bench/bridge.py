#!/usr/bin/env python3
"""Bridge benchmarks: throughput board -> graph subscriber, and service round-trip latency.

Three processes, as in real use: a *board* (a device-side protocol session on the master end of a
pty, in its own process), the *bridge* (this process: ``Bridge`` reading the pty's slave), and a
*client* (a graph subscriber, or a service caller, in its own process).

Throughput (``bench`` contains ``throughput``): the board writes N frames of 16-byte payloads as
fast as the link takes them (native frames come from 256 encodings made once, as a C firmware
would be fast enough to do: the measurement is from bytes arriving at the bridge, not of this
Python producer); the subscriber process counts what arrives in its callback. The peer is
``zenoh_raw``: this process publishing the same payloads straight to Zenoh, no link, framing or
session (the graph's own ceiling on this machine). CPU use of the bridge process is reported.

Latency (``bench`` contains ``latency``): the client calls a std_srvs/Trigger service served by
the board through the bridge. ``p50_us``/``p99_us`` are host-added: the round trip minus what
the host does not cause: the board's own processing (``board_us``, measured in the board
process) and the pty round trip (``pty_echo_us``, a raw echo over a pty measured in the same
run, which is also the ``peer``). The round trip itself is ``rtt_p50_us``/``rtt_p99_us``. That
echo runs back to back, so its two processes never sleep; in a bridged call the board sleeps
between calls and waking a sleeping process costs far more on some machines (a virtual one
most). ``pty_echo_idle_us`` is the echo with a pause between rounds as long as the board sleeps
in a bridged call, and ``p50_idle_echo_us`` the host-added p50 with that echo subtracted
instead: what the host adds when the link is charged at the price the call pays for it.
``p50_us`` stays the stricter figure. Two floors are measured by the same caller process right
after the bridged calls: ``graph_rtt_p50_us``, a graph-only service served in the bridge
process (no board, no link), and ``zenoh_rtt_p50_us``, a bare Zenoh querier calling a bare
Zenoh queryable there (no hwbridge code on either side). For both, the caller pauses between
calls so that, as in a bridged call, both processes go idle in between. (Interleaving the three
in small blocks was tried: each switch leaves the board and the bridge cold, which adds 65-100
us to the bridged p50, a cost a caller that keeps calling does not pay; the rounds below switch
once a round, after 50 warm-up calls of each.) ``p50_us`` minus ``graph_rtt_p50_us`` is about
what the bridge itself adds; ``graph_rtt_p50_us`` minus ``zenoh_rtt_p50_us`` is what the graph
layer adds to Zenoh.

The floor of a bridged call, ``floor_p50_us``, is what any bridge pays with this board and
these processes, summed from parts measured in the same run (``floor_parts_us``): a Zenoh round
trip (``zenoh_rtt_p50_us``), a round trip on the board's link with the board idle between
rounds (a raw echo process on the board's end of the same transport, ``pty://`` or
``tcp-listen://``, answering the request's bytes with as many bytes as the board's answer,
``frame_bytes``, paused as in a call) and the board's own handling (``board_us``, which a
Python board makes far longer than a C++ one). ``rtt_over_floor`` is what the bridge costs
beyond the floor, as a ratio: the latency case runs in ``LATENCY_ROUNDS`` rounds, each its
share of the calls, then its floors and its link's echo, and ``rtt_over_floor`` is the median
of the rounds' ratios (``rtt_over_floor_rounds``, each a round's p50 over that round's floor;
``rtt_p50_rounds_us`` and ``floor_rounds_us`` are the two). The other fields pool the rounds
(``floor_p50_us`` sums the pooled parts, the link's the median of the rounds'). The rounds show
how much one window of calls says: on the 2-core machine of issue 29 the rounds of one run read
1.03 to 1.57, the bridged p50 of 500 calls moving from 338 to 623 us between rounds while the
floors moved from 325 to 442 us; one pass (all calls, then the floors) read 1.06 to 1.50 over
four runs of one commit within an hour. ``rtt_over_zenoh_plus_link`` leaves the board's
handling out of the floor (it charges the board's time to the bridge). The floor's Zenoh part is
a queryable that replies inside Zenoh's callback; a bridge reads the board's answer on its own
thread and replies from there, which Zenoh makes dearer: ``zenoh_reply.py`` measures 19 to 31
us more per call at the p50 on the machine above (bare Zenoh, no hwbridge code), a part of
what ``rtt_over_floor`` counts as the bridge's. The floor's querier has the graph's options:
since graph calls stopped waiting for the query's final message (no consolidation), five runs
alternating with five of the commit before read a bridged p50 of 457-561 us against 484-573
and a Zenoh floor of 194-241 us against 241-275: the ratio stayed where it was (1.17-1.37
against 1.04-1.33), the floor having fallen with the calls.

``bridge_path_us`` says where the bridge's share goes: after the rounds, more calls run with
four stamps in this process (see ``_bridge_path``), and ``request`` (the query callback to the
request written to the link) and ``answer`` (the answer read to the reply handed to Zenoh) are
their p50s. On the machine of issue 29 (a 2-core VM, quiet) they read 42-54 and 33-43 us for
native, about as much for rosserial: most of a call's excess over its floor is this Python
(graph, pump, session, link) run cold, each process having slept while the other two ran. The
same stamps in finer steps put a native request's at 8-10 us in the graph's query callback, 3-4
in the pump's call, 13-16 in the session's ``call_service``, 9-11 encoding and 3-4 in the
link's ``write`` before the system call. A bare Zenoh queryable that writes the request to a
raw pty echo and replies from a thread that reads it (no hwbridge code) read 0.55 to 0.92 of
the same floor. Compiling that Python does not help: the 23 modules on the path built with
Cython (Python's semantics kept, loaded only for the source they were built from) halved the
host session's warm time (``session_call.py``), yet in six pairs alternating with the plain
modules on one tree the native ``rtt_over_floor`` read 1.30 to 1.58 compiled against 1.13 to
1.36 plain (rosserial 1.16 to 1.38 against 1.03 to 1.37): run cold, as each call runs it, the
compiled code is no faster (tried, measured and taken out again).

Runs with no arguments in about a minute; prints one JSON object per line. ``--cases latency``
runs only the service calls.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import emit

N_MESSAGES = 200_000
_DROP_COUNTERS = {
    "crc_errors",
    "bad_frames",
    "be_frames_lost",
    "be_messages_incomplete",
    "dropped_messages",
    "non_frame_bytes",
    "checksum_errors",
    "rx_length_checksum_errors",
    "rx_checksum_errors",
    "errors",
}
N_CALLS = 2000
GRAPH_PAUSE = 300e-6
"""Seconds the caller waits between calls to the floor services: about what the board and the
link take in a bridged call, so both processes go idle between messages as they do there."""
LATENCY_ROUNDS = 4
"""The latency case runs in rounds: each its share of the calls, its floors and its link echo,
one after the other, and its own ratio (see the module's docstring)."""
PATH_CALLS = 500
"""Calls at least of the latency case's last phase, which stamps the bridge's own steps
(``bridge_path_us``)."""
RAW_KEY = "bench_raw/trigger"
"""Key of the bare Zenoh queryable (outside the graph's key space)."""
DOMAIN = "bench"


def _trigger_ok() -> bytes:
    """The answer every benchmark service gives: a std_srvs/Trigger success."""
    from hwbridge import msg

    return msg.encode(msg.new("std_srvs/TriggerResponse", success=True, message="ok"))


# ---------------------------------------------------------------------------------- the board
def board_main(protocol: str, url: str) -> None:
    """Board process: negotiate, then on stdin commands blast frames or serve calls."""
    from hwbridge import msg
    from hwbridge.links import open_link
    from hwbridge.pump import SessionPump

    registry = msg.registry()
    payload = msg.encode(msg.new("std_msgs/String", data="0123456789ab"))  # 16 bytes
    reply = _trigger_ok()
    link = open_link(url)
    handling: list[float] = []
    pump: SessionPump

    if protocol == "native":
        from hwbridge.protocols.native import session as ns
        from hwbridge.protocols.native.control import EntryKind

        session: Any = _fast_publisher_class()(
            ns.BoardInfo("bench", b"\x01", "1"),
            [
                ns.TopicEntry(
                    1,
                    EntryKind.PUBLISHER,
                    "data",
                    "std_msgs/String",
                    registry.md5("std_msgs/String"),
                ),
                ns.TopicEntry(
                    2,
                    EntryKind.SERVICE_SERVER,
                    "trigger",
                    "std_srvs/Trigger",
                    registry.service("std_srvs/Trigger").md5,
                ),
            ],
            ns.DeviceConfig(mtu=255, max_message=1024, window=8, tx_queue_limit=1 << 20),
        )

        def on_event(event: Any) -> None:
            if isinstance(event, ns.ServiceRequest):
                timer.answered = True
                pump.call(lambda s: s.respond_service(event.channel, event.request_id, reply))

        def send_all(count: int) -> None:
            """Publish through the session in batches, each encoded and written under the
            pump's lock (nothing of the session's own comes in between)."""
            for start in range(0, count, 4097):  # one publish() and 16 replayed cycles
                size = min(4097, count - start)
                pump.call(lambda s, size=size: s.publish_repeated(1, payload, size))

    else:
        from hwbridge.protocols.rosserial import RosserialDevice, encode_frame

        device = RosserialDevice(registry)
        device.advertise("data", "std_msgs/String")

        def serve(_request: bytes) -> bytes:
            timer.answered = True
            return reply

        device.advertise_service("trigger", "std_srvs/Trigger", serve)
        session = device

        def on_event(event: Any) -> None:
            return None

        frame = encode_frame(device.topic_id("data"), payload)
        per_write = 4096 // len(frame)

        def send_all(count: int) -> None:
            """Whole frames per write (rosserial frames carry no sequence numbers)."""
            for start in range(0, count, per_write):
                link.write(frame * min(per_write, count - start))

    timer = _BoardTimer(session, handling)
    pump = SessionPump(link, timer, on_event, name="bench-board")
    pump.start()
    print("ready", flush=True)
    to_send = 0
    for line in sys.stdin:
        command, _, arg = line.strip().partition(" ")
        if command == "prepare":
            to_send = int(arg)
            print("prepared", flush=True)
        elif command == "go":
            send_all(to_send)
            print("sent", flush=True)
        elif command == "handling":
            sizes = {"request_bytes": timer.request_bytes, "reply_bytes": timer.reply_bytes}
            print(json.dumps({"seconds": handling, **sizes}), flush=True)
        elif command == "quit":
            break
    pump.stop()
    link.close()


def _fast_publisher_class() -> type:
    from hwbridge.protocols.native import session as ns
    from hwbridge.protocols.native.framing import Frame, FrameType, NativeStreamFraming

    class FastPublisher(ns.DeviceSession):
        """A device session that publishes like a C firmware: fast enough that the bridge, not
        this Python process, limits the throughput bench. Public API only.

        ``publish_repeated(channel, payload, count)`` puts on the wire the bytes that ``count``
        calls of ``publish(channel, payload)`` would. The encoding of the message under each
        of the 256 best-effort sequence numbers is kept from ``publish``'s own output; since
        the number wraps at 256, whole cycles of 256 are those bytes again, starting after the
        number that the latest ``publish`` used (the session's other best-effort frames, such
        as heartbeats, move it too). The rest goes through ``publish``. Replayed frames skip
        the session, so its own counters do not count them (the host's do).
        """

        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self._tables: dict[tuple[int, bytes], list[bytes | None]] = {}
            self._replayed: list[bytes] = []

        def chunks_to_send(self) -> list[bytes]:
            own = super().chunks_to_send()
            if not self._replayed:
                return own
            chunks, self._replayed = [*self._replayed, *own], []
            return chunks

        def _publish_one(self, channel: int, payload: bytes, table: list[bytes | None]) -> int:
            """``publish`` once, keep its frame's encoding; returns its sequence number (-1 if
            its output was not that one frame alone)."""
            self.publish(channel, payload)
            chunk = b"".join(super().chunks_to_send())
            self._replayed.append(chunk)
            frames = NativeStreamFraming().decode(chunk)
            if len(frames) != 1:
                return -1
            (frame,) = frames
            if not isinstance(frame, Frame) or frame.type is not FrameType.BEST_EFFORT:
                return -1
            table[frame.seq] = chunk.lstrip(b"\x00")
            return frame.seq

        def publish_repeated(self, channel: int, payload: bytes, count: int) -> None:
            table = self._tables.setdefault((channel, payload), [None] * 256)
            while count > 0:
                seq = self._publish_one(channel, payload, table)
                count -= 1
                cycles = count // 256
                if seq >= 0 and cycles and None not in table:
                    rotated = table[seq + 1 :] + table[: seq + 1]
                    self._replayed.append(b"".join(rotated) * cycles)  # type: ignore[arg-type]
                    for _ in range(count - cycles * 256):
                        self.publish(channel, payload)
                    return

    return FastPublisher


class _BoardTimer:
    """Wraps the board's session to time each service call on the board: from the moment the
    request's bytes are handed to the session to the moment the answer's bytes leave it."""

    def __init__(self, inner: Any, samples: list[float]) -> None:
        self.inner = inner
        self.samples = samples
        self.request_bytes: list[int] = []
        """Per answered call: bytes of the link read that brought the request."""
        self.reply_bytes: list[int] = []
        """Per answered call: bytes written with the answer (a held ACK rides along)."""
        self.answered = False
        self._received_at: float | None = None
        self._read_size = 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def receive_data(self, data: bytes, now: float) -> list[Any]:
        self._received_at = time.perf_counter()
        self._read_size = len(data)
        result: list[Any] = self.inner.receive_data(data, now)
        return result

    def tick(self, now: float) -> list[Any]:
        result: list[Any] = self.inner.tick(now)
        return result

    def chunks_to_send(self) -> list[bytes]:
        chunks: list[bytes] = self.inner.chunks_to_send()
        if chunks and self.answered and self._received_at is not None:
            self.samples.append(time.perf_counter() - self._received_at)
            self.request_bytes.append(self._read_size)
            self.reply_bytes.append(sum(map(len, chunks)))
            self.answered = False
            self._received_at = None
        return chunks


def echo_main(url: str, request_size: int = 16, reply_size: int = 16) -> None:
    """A raw echo on a link (the board's end: ``pty://`` or ``tcp-listen://``): the round trip a
    link costs without any protocol. Each ``request_size`` bytes read are answered with
    ``reply_size`` bytes (a service call's frames are not the same size both ways)."""
    from hwbridge.links import LinkClosedError, open_link

    link = open_link(url)
    reply = b"\x00" * reply_size
    print("ready", flush=True)
    pending = 0
    while True:
        try:
            data = link.read(4096, timeout=1.0)
        except LinkClosedError:
            break
        pending += len(data)
        while pending >= request_size:
            pending -= request_size
            link.write(reply)


# ---------------------------------------------------------------------------------- the client
def subscriber_main(endpoint: str, topic: str, expected: int) -> None:
    from hwbridge.graph import ANY_TYPE, Graph

    count = 0
    first = last = 0.0
    done = threading.Event()

    def on_message(_message: Any) -> None:
        nonlocal count, first, last
        now = time.perf_counter()
        if count == 0:
            first = now
        count += 1
        last = now
        if count >= expected:
            done.set()

    with Graph.attached(connect=[endpoint], domain=DOMAIN) as graph:
        graph.node("bench_sub").subscriber(topic, ANY_TYPE, on_message, raw=True)
        print("ready", flush=True)
        while not done.wait(0.5):
            if count and time.perf_counter() - last > 3.0:
                break
        print(json.dumps({"count": count, "seconds": last - first}), flush=True)


def caller_main(endpoint: str, calls: int, targets: list[str]) -> None:
    """Time ``calls`` calls of each target, one target after the other; prints
    {target: [seconds]}.

    A target is ``SERVICE`` (a graph service, no pause), ``SERVICE@PAUSE`` (seconds to wait
    after each call) or ``zenoh:KEY@PAUSE`` (a bare Zenoh querier on KEY, no hwbridge code).
    """
    import zenoh

    from hwbridge.graph import Graph

    with Graph.attached(connect=[endpoint], domain=DOMAIN) as graph:
        node = graph.node("bench_caller")
        plans: list[tuple[str, Callable[[], None], float]] = []
        for target in targets:
            name, _, pause_text = target.partition("@")
            pause = float(pause_text or 0.0)
            if name.startswith("zenoh:"):
                # The graph's own querier options (express: no wait for Zenoh's batching; no
                # consolidation: the reply is taken as it comes, not at the query's end).
                querier = graph.keep(
                    graph.session.declare_querier(
                        name[len("zenoh:") :],
                        target=zenoh.QueryTarget.BEST_MATCHING,
                        consolidation=zenoh.ConsolidationMode.NONE,
                        timeout=2.0,
                        express=True,
                    )
                )
                call = _bare_call(querier)
            else:
                call = _graph_call(node, name)
            for _ in range(50):  # warm up (and wait until the target is there)
                try:
                    call()
                except Exception:  # noqa: BLE001 - not there yet
                    time.sleep(0.1)
            plans.append((target, call, pause))
        times: dict[str, list[float]] = {target: [] for target in targets}
        clock = time.perf_counter
        for target, call, pause in plans:
            record = times[target].append
            for _ in range(calls):
                started = clock()
                call()
                record(clock() - started)
                if pause:
                    time.sleep(pause)
        print(json.dumps(times), flush=True)


def _bare_call(querier: Any) -> Callable[[], None]:
    def call() -> None:
        for reply in querier.get(payload=b""):
            if reply.ok is None:
                raise RuntimeError(f"bare Zenoh call failed: {reply.err}")
            reply.ok.payload.to_bytes()
            return
        raise RuntimeError("bare Zenoh call: no answer")

    return call


def _graph_call(node: Any, service: str) -> Callable[[], None]:
    return lambda: node.call_raw(service, "std_srvs/Trigger", b"", timeout=2.0)


def echo_client_main(
    url: str, rounds: int, pause: float = 0.0, request_size: int = 16, reply_size: int = 16
) -> None:
    """Time ``rounds`` round trips to :func:`echo_main` over the link at ``url`` (the bridge's
    end: ``serial://`` or ``socket://``), ``pause`` seconds apart; prints [seconds]."""
    from hwbridge.links import open_link

    link = open_link(url)
    request = b"\x00" * request_size
    times = []
    for _ in range(rounds):
        started = time.perf_counter()
        link.write(request)
        got = 0
        while got < reply_size:
            got += len(link.read(4096, timeout=1.0))
        times.append(time.perf_counter() - started)
        if pause:
            time.sleep(pause)
    link.close()
    print(json.dumps(times), flush=True)


# ---------------------------------------------------------------------------------- orchestration
def _spawn(*args: str) -> subprocess.Popen[str]:
    process = subprocess.Popen(
        [sys.executable, __file__, *args],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert process.stdout is not None
    line = process.stdout.readline().strip()
    if line != "ready":
        process.kill()
        raise RuntimeError(f"{args[0]} did not start: {line!r}")
    return process


def _ask(process: subprocess.Popen[str], command: str) -> str:
    assert process.stdin is not None and process.stdout is not None
    process.stdin.write(command + "\n")
    process.stdin.flush()
    return process.stdout.readline().strip()


def _percentile(values: list[float], fraction: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(fraction * len(ordered)))]


def _free_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def run_protocol(
    protocol: str, transport: str, tmp: Path, messages: int, calls: int, echo_rtt: float
) -> None:
    from hwbridge.bridge import BoardSpec, Bridge
    from hwbridge.graph import Graph

    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    if transport == "pty":
        path = tmp / f"tty-{protocol}"
        board = _spawn("--board", protocol, f"pty://?symlink={path}")
        board_url = str(path)
    else:
        port = _free_port()
        board = _spawn("--board", protocol, f"tcp-listen://127.0.0.1:{port}")
        board_url = f"socket://127.0.0.1:{port}"
    name = "board"
    graph = Graph.embedded(listen=[endpoint], domain=DOMAIN)
    bridge = Bridge(graph)
    bridge.add_board(
        BoardSpec(board_url, protocol=protocol, namespace="/bench", start_delay=0.1, name=name)
    )
    try:
        deadline = time.monotonic() + 30
        while bridge.boards[name].state != "connected":
            if time.monotonic() > deadline:
                raise RuntimeError(f"{protocol} board did not connect")
            time.sleep(0.05)
        if messages:
            _throughput(bridge, board, graph, endpoint, name, protocol, transport, messages)
        if calls:
            _latency(board, graph, endpoint, protocol, transport, tmp, calls, echo_rtt)
    finally:
        bridge.stop()  # first: a board that quits under a running bridge is a lost link to it
        _ask(board, "quit")
        board.wait(10)
        graph.close()


def _throughput(
    bridge: Any,
    board: subprocess.Popen[str],
    graph: Any,
    endpoint: str,
    name: str,
    protocol: str,
    transport: str,
    messages: int,
) -> None:
    """Board -> bridge -> subscriber process, against Zenoh alone (one JSON line)."""
    sub = _spawn("--subscriber", endpoint, "/bench/data", str(messages))
    time.sleep(1.0)  # let the subscription reach the bridge
    _ask(board, f"prepare {messages}")
    cpu0, wall0 = time.process_time(), time.perf_counter()
    _ask(board, "go")
    assert sub.stdout is not None
    result = json.loads(sub.stdout.readline())
    cpu = (time.process_time() - cpu0) / max(time.perf_counter() - wall0, 1e-9)
    sub.wait(10)
    rate = result["count"] / result["seconds"] if result["seconds"] > 0 else 0.0
    stats = bridge.boards[name].info()
    counted = {
        key: value
        for key, value in {**stats["stats"], **stats["link"]}.items()
        if key in _DROP_COUNTERS and value
    }
    raw = zenoh_raw_rate(graph, endpoint, messages)
    emit(
        f"bridge_throughput_{protocol}_{transport}",
        {"payload": 16},
        rate,
        "zenoh_raw",
        raw,
        received=result["count"],
        sent=messages,
        bridge_cpu_fraction=round(cpu, 3),
        bridge_drop_counters=counted,
    )


def _latency(
    board: subprocess.Popen[str],
    graph: Any,
    endpoint: str,
    protocol: str,
    transport: str,
    tmp: Path,
    calls: int,
    echo_rtt: float,
) -> None:
    """Service calls through the bridge, against their floor (one JSON line)."""
    answer = _trigger_ok()
    graph.node("bench_graph").service(
        "/bench/graph_trigger", "std_srvs/Trigger", lambda _request: answer, raw=True
    )
    raw_server = graph.session.declare_queryable(
        RAW_KEY, lambda query: query.reply(RAW_KEY, answer, express=True)
    )
    floors = f"@{GRAPH_PAUSE!r}"
    targets = ["/bench/trigger", "/bench/graph_trigger" + floors, f"zenoh:{RAW_KEY}" + floors]
    times: list[float] = []
    graph_times: list[float] = []
    zenoh_times: list[float] = []
    rounds: list[_Round] = []
    handled = 0  # the board's handling times taken by the rounds before
    handling: dict[str, list[Any]] = {"seconds": []}
    sizes = (16, 16)
    try:
        count = max(1, min(LATENCY_ROUNDS, calls))  # a round has at least one call
        for index in range(count):
            share = calls // count + (index < calls % count)
            measured = _call_times(endpoint, share, targets)
            handling = json.loads(_ask(board, "handling"))
            seconds, handled = handling["seconds"][handled:], len(handling["seconds"])
            sizes = (
                int(statistics.median(handling["request_bytes"] or [16])),
                int(statistics.median(handling["reply_bytes"] or [16])),
            )
            rounds.append(
                _floor_round(
                    measured[targets[0]],
                    measured[targets[2]],
                    seconds,
                    sizes,
                    echo_rtt,
                    tmp,
                    transport,
                )
            )
            times += measured[targets[0]]
            graph_times += measured[targets[1]]
            zenoh_times += measured[targets[2]]
    finally:
        raw_server.undeclare()
    path = _bridge_path(endpoint, max(PATH_CALLS, calls // count), targets[0])
    board_time = statistics.median(handling["seconds"]) if handling["seconds"] else 0.0
    host = [t - echo_rtt - board_time for t in times]
    # The same echo with each side idle between rounds as long as the board is in a bridged
    # call (the rest of the round trip): the pty round trip as the call meets it.
    idle = max(_percentile(times, 0.5) - board_time - echo_rtt, 0.0)
    echo_idle = pty_echo_rtt(tmp, 500, pause=idle)
    link_idle = statistics.median(r.link for r in rounds)
    rtt_p50 = _percentile(times, 0.5)
    zenoh_p50 = _percentile(zenoh_times, 0.5)
    floor = zenoh_p50 + link_idle + board_time
    ratios = [r.rtt / r.floor for r in rounds]
    emit(
        f"bridge_latency_{protocol}_{transport}",
        {"payload": 0},
        1.0 / statistics.mean(times),
        "pty_echo",
        1.0 / echo_rtt,
        p50_us=round(_percentile(host, 0.5) * 1e6, 1),
        p99_us=round(_percentile(host, 0.99) * 1e6, 1),
        rtt_p50_us=round(_percentile(times, 0.5) * 1e6, 1),
        rtt_p99_us=round(_percentile(times, 0.99) * 1e6, 1),
        board_us=round(board_time * 1e6, 1),
        pty_echo_us=round(echo_rtt * 1e6, 1),
        pty_echo_idle_us=round(echo_idle * 1e6, 1),
        p50_idle_echo_us=round(_percentile([t + echo_rtt - echo_idle for t in host], 0.5) * 1e6, 1),
        graph_rtt_p50_us=round(_percentile(graph_times, 0.5) * 1e6, 1),
        zenoh_rtt_p50_us=round(zenoh_p50 * 1e6, 1),
        floor_p50_us=round(floor * 1e6, 1),
        floor_parts_us={
            "zenoh_rtt": round(zenoh_p50 * 1e6, 1),
            f"{transport}_rtt_idle": round(link_idle * 1e6, 1),
            "board": round(board_time * 1e6, 1),
        },
        frame_bytes={"request": sizes[0], "reply": sizes[1]},
        rtt_over_floor=round(statistics.median(ratios), 3),
        rtt_over_floor_rounds=[round(ratio, 3) for ratio in ratios],
        rtt_p50_rounds_us=[round(r.rtt * 1e6, 1) for r in rounds],
        floor_rounds_us=[round(r.floor * 1e6, 1) for r in rounds],
        rtt_over_zenoh_plus_link=round(rtt_p50 / (zenoh_p50 + link_idle), 3),
        bridge_path_us=path,
        calls=len(times),
    )


def _bridge_path(endpoint: str, calls: int, service: str) -> dict[str, float]:
    """The bridge's own Python on a call's way, p50 in us over ``calls`` more calls of
    ``service``, stamped in this process (the bridge's) while they run: ``request`` from the
    call's ``DeferredReply`` made in the query callback to the end of the link write that takes
    the request to the board, ``answer`` from the end of the link read that brought the board's
    answer to the reply handed to Zenoh. The stamps wrap four methods for this phase only (the
    rounds run without them); a wrapper adds well under a microsecond."""
    from hwbridge.graph import DeferredReply
    from hwbridge.links import Link

    clock = time.perf_counter
    last = {"write": 0.0, "read": 0.0}
    made: list[float] = []
    request: list[float] = []
    answer: list[float] = []
    originals = (DeferredReply.__init__, DeferredReply.ok, Link.write, Link.read)
    init, ok, write, read = originals

    def timed_init(self: Any, query: Any, server: Any) -> None:
        made.append(clock())
        init(self, query, server)

    def timed_ok(self: Any, payload: bytes) -> None:
        answer.append(clock() - last["read"])
        if made and last["write"] > made[-1]:
            request.append(last["write"] - made[-1])
        ok(self, payload)

    def timed_write(self: Any, data: Any) -> None:
        write(self, data)
        last["write"] = clock()

    def timed_read(self: Any, *args: Any, **kwargs: Any) -> bytes:
        data: bytes = read(self, *args, **kwargs)
        if data:
            last["read"] = clock()
        return data

    wrapped = (timed_init, timed_ok, timed_write, timed_read)
    places = ((DeferredReply, "__init__"), (DeferredReply, "ok"), (Link, "write"), (Link, "read"))
    try:
        for (owner, name), function in zip(places, wrapped, strict=True):
            setattr(owner, name, function)
        _call_times(endpoint, calls, [service])
    finally:
        for (owner, name), function in zip(places, originals, strict=True):
            setattr(owner, name, function)
    return {
        "request": round(_percentile(request, 0.5) * 1e6, 1) if request else 0.0,
        "answer": round(_percentile(answer, 0.5) * 1e6, 1) if answer else 0.0,
    }


@dataclass(frozen=True)
class _Round:
    """One round of the latency case: its bridged calls' p50 and the floor measured with them
    (seconds), and the floor's link part."""

    rtt: float
    floor: float
    link: float


def _floor_round(
    times: list[float],
    zenoh_times: list[float],
    board_seconds: list[float],
    sizes: tuple[int, int],
    echo_rtt: float,
    tmp: Path,
    transport: str,
) -> _Round:
    """A round's floor: its Zenoh round trip, the board's handling in it, and the link's idle
    echo measured right after it, with the call's own frame sizes each way, paused as long as
    the rest of the call keeps the board's end idle."""
    board_time = statistics.median(board_seconds) if board_seconds else 0.0
    rtt = _percentile(times, 0.5)
    idle = max(rtt - board_time - echo_rtt, 0.0)
    link = pty_echo_rtt(tmp, 500, pause=idle, transport=transport, sizes=sizes)
    return _Round(rtt, _percentile(zenoh_times, 0.5) + link + board_time, link)


def _call_times(endpoint: str, calls: int, targets: list[str]) -> dict[str, list[float]]:
    """Round trips (seconds) of ``calls`` calls to each target, made by one caller process."""
    caller = subprocess.run(
        [sys.executable, __file__, "--caller", endpoint, str(calls), *targets],
        capture_output=True,
        text=True,
        timeout=600,
        check=True,
    )
    times: dict[str, list[float]] = json.loads(caller.stdout.splitlines()[-1])
    return times


def zenoh_raw_rate(graph: Any, endpoint: str, messages: int) -> float:
    """The peer: the same payloads published straight to Zenoh from this process."""
    sub = _spawn("--subscriber", endpoint, "/bench/raw", str(messages))
    time.sleep(1.0)
    publisher = graph.node("bench_raw").raw_publisher("/bench/raw", "std_msgs/String", "0" * 32)
    payload = b"\x0c\x00\x00\x000123456789ab"
    for _ in range(messages):
        publisher.publish_raw(payload)
    assert sub.stdout is not None
    result = json.loads(sub.stdout.readline())
    sub.wait(10)
    publisher.close()
    return float(result["count"] / result["seconds"]) if result["seconds"] > 0 else 0.0


def pty_echo_rtt(
    tmp: Path,
    rounds: int,
    pause: float = 0.0,
    transport: str = "pty",
    sizes: tuple[int, int] = (16, 16),
) -> float:
    """Median round trip through a raw echo on the ``transport`` a board uses (``pty`` or
    ``tcp``): ``sizes`` bytes out and back, ``pause`` seconds between rounds."""
    if transport == "pty":
        path = tmp / "tty-echo"
        board_end, bridge_end = f"pty://?symlink={path}", f"serial://{path}"
    else:
        port = _free_port()
        board_end, bridge_end = f"tcp-listen://127.0.0.1:{port}", f"socket://127.0.0.1:{port}"
    echo = _spawn("--echo", board_end, *map(str, sizes))
    try:
        done = subprocess.run(
            [
                sys.executable,
                __file__,
                "--echo-client",
                bridge_end,
                str(rounds),
                *map(str, sizes),
                f"--pause={pause}",
            ],
            capture_output=True,
            text=True,
            timeout=120,
            check=True,
        )
        return float(statistics.median(json.loads(done.stdout.splitlines()[-1])))
    finally:
        echo.kill()
        echo.wait(5)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--board", nargs=2, metavar=("PROTOCOL", "PATH"))
    parser.add_argument("--echo", nargs=3, metavar=("URL", "REQUEST_BYTES", "REPLY_BYTES"))
    parser.add_argument(
        "--echo-client", nargs=4, metavar=("URL", "ROUNDS", "REQUEST_BYTES", "REPLY_BYTES")
    )
    parser.add_argument("--pause", type=float, default=0.0, help=argparse.SUPPRESS)
    parser.add_argument("--subscriber", nargs=3, metavar=("ENDPOINT", "TOPIC", "N"))
    parser.add_argument("--caller", nargs="+", metavar="ENDPOINT N TARGET")
    parser.add_argument("--messages", type=int, default=N_MESSAGES)
    parser.add_argument("--calls", type=int, default=N_CALLS)
    parser.add_argument("--protocol", choices=["native", "rosserial", "both"], default="both")
    parser.add_argument(
        "--cases",
        nargs="+",
        choices=["throughput", "latency"],
        default=["throughput", "latency"],
        help="which measurements to run (default: both)",
    )
    parser.add_argument(
        "--transport",
        nargs="+",
        choices=["pty", "tcp"],
        default=["pty", "tcp"],
        help="pty: the board on a pseudo-terminal (a serial port); tcp: a WiFi-style socket",
    )
    args = parser.parse_args()
    if args.board:
        board_main(*args.board)
    elif args.echo:
        echo_main(args.echo[0], int(args.echo[1]), int(args.echo[2]))
    elif args.echo_client:
        url, rounds, request_size, reply_size = args.echo_client
        echo_client_main(url, int(rounds), args.pause, int(request_size), int(reply_size))
    elif args.subscriber:
        subscriber_main(args.subscriber[0], args.subscriber[1], int(args.subscriber[2]))
    elif args.caller:
        caller_main(args.caller[0], int(args.caller[1]), args.caller[2:])
    else:
        os.environ.setdefault("HWBRIDGE_DOMAIN", DOMAIN)
        with tempfile.TemporaryDirectory() as tmp:
            echo = pty_echo_rtt(Path(tmp), 500)
            protocols = ["native", "rosserial"] if args.protocol == "both" else [args.protocol]
            for protocol in protocols:
                for transport in args.transport:
                    run_protocol(
                        protocol,
                        transport,
                        Path(tmp),
                        args.messages if "throughput" in args.cases else 0,
                        args.calls if "latency" in args.cases else 0,
                        echo,
                    )


if __name__ == "__main__":
    main()
