#!/usr/bin/env python3
"""What a Zenoh reply costs when it leaves from a thread other than the one Zenoh called.

A bridge reads a board's answer on its own thread (the pump's) and replies to the graph's query
from there: ``bridge.py``'s floor has the Zenoh round trip of a queryable that replies inside
its callback, so it leaves this out. Two processes, bare Zenoh (no hwbridge code; the graph's
loopback configuration): a querier in this process calls, one call at a time with a pause of
``--pause`` seconds between calls (both processes go idle, as in ``bridge.py``), three
queryables in a child process:

- ``inline``: the reply is sent inside Zenoh's callback (the floor's queryable, the peer);
- ``other_thread``: the callback hands the query to a thread that is already running (it polls
  a queue, yielding the GIL between looks), which replies: the cost of the thread alone, no
  wake-up;
- ``other_thread_woken``: the callback writes a byte to a pipe that the other thread waits on
  in ``select()``, as a pump waits on its link; that thread wakes and replies.

Each reply is express and the query is dropped at once, as ``DeferredReply.ok`` does; the
querier has the graph's options (express, no consolidation: the reply is taken as it comes, not
at the query's end). The calls go in blocks of 50, the three kinds in turn. One JSON line:
``hwbridge_per_s`` is calls per second with the reply from the other thread, ``peer_per_s`` with
the inline reply; the p50 round trips of each kind, ``other_thread_extra_us`` (what the thread
alone adds to the p50) and ``woken_extra_us``. Measured on the 2-core machine of issue 29, five
runs: the other thread added 21 to 31 us to an inline p50 of 215 to 264 us (8 to 12 %), the
woken one 16 to 32 us. The same through hwbridge's graph (a ``deferred_service`` answered from
another thread against a plain ``service``) read 30 to 38 us more over four runs. Those runs had
Zenoh's default consolidation, which holds a reply until the query's final message; without it
(three runs, alternating with three of the old querier) the inline p50 fell from 255-268 to
229-244 us and the other thread still added 19 to 28 us.

Runs in about 10 seconds with the defaults.
"""

from __future__ import annotations

import argparse
import collections
import os
import select
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import emit, free_port

KINDS = ("inline", "other_thread_woken", "inline_direct", "woken_direct")
ANSWER = b"\x01\x00\x00\x00\x00"
"""A std_srvs/Trigger response: success, no message."""
BLOCK = 50


def _config(endpoint: str, listen: bool) -> Any:
    from hwbridge.graph.config import GraphConfig

    graph = GraphConfig.embedded([endpoint]) if listen else GraphConfig.attached([endpoint])
    return graph.to_zenoh()


def serve(endpoint: str) -> None:
    """The three queryables, until stdin closes."""
    import zenoh

    session: Any = zenoh.open(_config(endpoint, listen=True))
    polled: collections.deque[Any] = collections.deque()
    woken: collections.deque[Any] = collections.deque()
    wake_r, wake_w = os.pipe()
    stop = threading.Event()

    def answer(query: Any) -> None:
        query.reply(query.key_expr, ANSWER, express=True)
        query.drop()

    def poller() -> None:
        while not stop.is_set():
            if polled:
                answer(polled.popleft())
            else:
                time.sleep(0)  # let the callback's thread take the GIL

    def waiter() -> None:
        while not stop.is_set():
            ready, _, _ = select.select([wake_r], [], [], 0.5)
            if ready:
                os.read(wake_r, 64)
            while woken:
                answer(woken.popleft())

    def hand_on(query: Any) -> None:
        woken.append(query)
        os.write(wake_w, b"x")

    threads = [threading.Thread(target=f, daemon=True) for f in (poller, waiter)]
    for thread in threads:
        thread.start()
    queryables: list[Any] = [
        session.declare_queryable(
            "bench_reply/inline", lambda q: q.reply(q.key_expr, ANSWER, express=True)
        ),
        session.declare_queryable("bench_reply/inline_direct", zenoh.handlers.Callback(lambda q: q.reply(q.key_expr, ANSWER, express=True), indirect=False)),
        session.declare_queryable("bench_reply/woken_direct", zenoh.handlers.Callback(hand_on, indirect=False)),
        session.declare_queryable("bench_reply/other_thread_woken", hand_on),
    ]
    print("ready", flush=True)
    try:
        sys.stdin.read()
    finally:
        stop.set()
        for thread in threads:
            thread.join(2.0)
        for queryable in queryables:
            queryable.undeclare()
        session.close()


def call_all(endpoint: str, calls: int, pause: float) -> dict[str, list[float]]:
    """Round trips (s) of ``calls`` calls of each kind, in blocks of BLOCK, kinds in turn."""
    import zenoh

    session: Any = zenoh.open(_config(endpoint, listen=False))
    try:
        queriers: dict[str, Any] = {
            kind: session.declare_querier(
                f"bench_reply/{kind}",
                target=zenoh.QueryTarget.BEST_MATCHING,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=2.0,
                express=True,
            )
            for kind in KINDS
        }

        def call(kind: str) -> None:
            for reply in queriers[kind].get(payload=b""):
                if reply.ok is None:
                    raise RuntimeError(f"{kind}: {reply.err}")
                return
            raise RuntimeError(f"{kind}: no answer")

        deadline = time.monotonic() + 20
        for kind in KINDS:  # the queryables are there, and everything warm
            answered = 0
            while answered < BLOCK:
                try:
                    call(kind)
                    answered += 1
                except RuntimeError:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.1)
        times: dict[str, list[float]] = {kind: [] for kind in KINDS}
        clock = time.perf_counter
        while len(times[KINDS[-1]]) < calls:
            for kind in KINDS:
                for _ in range(min(BLOCK, calls - len(times[kind]))):
                    time.sleep(pause)
                    started = clock()
                    call(kind)
                    times[kind].append(clock() - started)
        for querier in queriers.values():
            querier.undeclare()
        return times
    finally:
        session.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--calls", type=int, default=3000, help="calls of each kind")
    parser.add_argument("--pause", type=float, default=300e-6, help="seconds between calls")
    parser.add_argument("--serve", metavar="ENDPOINT", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        serve(args.serve)
        return
    if args.calls < 1:
        parser.error("--calls must be at least 1")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    server = subprocess.Popen(
        [sys.executable, __file__, "--serve", endpoint],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert server.stdout is not None
        if server.stdout.readline().strip() != "ready":
            raise RuntimeError("the queryables' process did not start")
        times = call_all(endpoint, args.calls, args.pause)
    finally:
        if server.stdin is not None:
            server.stdin.close()
        try:
            server.wait(10)
        except subprocess.TimeoutExpired:
            server.kill()
    p50 = {kind: statistics.median(times[kind]) for kind in KINDS}
    emit(
        "zenoh_reply",
        {"pause_us": round(args.pause * 1e6)},
        1.0 / statistics.mean(times["inline"]),
        "inline_reply",
        1.0 / statistics.mean(times["inline"]),
        **{f"{kind}_p50_us": round(p50[kind] * 1e6, 1) for kind in KINDS},
        woken_extra_us=round((p50["other_thread_woken"] - p50["inline"]) * 1e6, 1),
        calls=args.calls,
    )


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:
        sys.exit(130)
