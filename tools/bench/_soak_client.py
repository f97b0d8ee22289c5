"""The soak bench's client process: subscribes to every board's topics over Zenoh, counts
their messages and measures latency, and calls every board's service once a second."""

from __future__ import annotations

import json
import sys
import threading
import time
from typing import Any

from _soak_board import board_name, topic_name

DOMAIN = "soak_bench"
BIN_S = 1e-4
"""Latency histogram resolution (0.1 ms)."""
BINS = 30_000
"""Histogram bins (up to 3 s; later arrivals count in the last bin)."""


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
