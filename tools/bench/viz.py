#!/usr/bin/env python3
"""Foxglove view benchmark: hwbridge's own WebSocket server (``hwbridge.viz.foxglove``) against
foxglove-sdk's server (Rust, ``foxglove.start_server``) fed the same way, in one run.

This process owns a graph and publishes ``sensor_msgs/Imu`` (ROS 1 bytes, the wall-clock time
in ``header.stamp``) on ``/bench/imu``. Each server serves that topic: ours subscribes to the
graph itself; the peer gets each message from a graph subscriber that calls ``Channel.log``
(what ``hwbridge viz`` did with the SDK). A viewer in a process of its own (this script with
``--client``, a ``websockets`` client offering ``foxglove.sdk.v1``, which both accept) subscribes
and takes ``now - header.stamp`` as each message's latency. Cases:

- ``robot_500hz``: 500 messages/s for a few seconds (ten topics at 50 Hz: a busy small robot);
  delivered fraction and latency p50/p99 of both servers.
- ``flood``: published as fast as this process can for a few seconds; ``hwbridge_per_s`` and
  ``peer_per_s`` are what the viewer received per second. Latencies in a flood are queueing.

Prints one JSON object per line (tools/bench/_common.py's fields).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve()
sys.path.insert(0, str(HERE.parents[2]))
sys.path.insert(0, str(HERE.parent))

from _common import emit  # noqa: E402

TOPIC = "/bench/imu"
TYPE = "sensor_msgs/Imu"


# ------------------------------------------------------------------------------- viewer process
def client(url: str, seconds: float) -> None:
    """Subscribe to TOPIC on ``url``; print a JSON summary after ``seconds`` of messages."""
    import struct

    from websockets.sync.client import connect

    latencies: list[float] = []
    with connect(url, subprotocols=["foxglove.sdk.v1"], open_timeout=10, max_size=None) as ws:  # type: ignore[list-item]
        deadline = time.monotonic() + 30
        subscribed = False
        first: float | None = None
        while True:
            now = time.monotonic()
            if first is not None and now - first > seconds:
                break
            if now > deadline and first is None:
                break
            try:
                frame = ws.recv(timeout=0.5)
            except TimeoutError:
                continue
            if isinstance(frame, str):
                message = json.loads(frame)
                if message["op"] == "advertise" and not subscribed:
                    for channel in message["channels"]:
                        if channel["topic"] == TOPIC:
                            ws.send(
                                json.dumps(
                                    {
                                        "op": "subscribe",
                                        "subscriptions": [{"id": 7, "channelId": channel["id"]}],
                                    }
                                )
                            )
                            subscribed = True
                continue
            if frame[0] != 1:
                continue
            sec, nsec = struct.unpack_from("<II", frame, 13 + 4)  # after header.seq
            latencies.append(time.time() - (sec + nsec * 1e-9))
            if first is None:
                first = time.monotonic()
    ordered = sorted(latencies)  # a summary: a long list would fill the pipe while we publish
    summary = {
        "received": len(ordered),
        "p50_ms": round(statistics.median(ordered) * 1e3, 3) if ordered else None,
        "p99_ms": round(ordered[int(len(ordered) * 0.99)] * 1e3, 3) if ordered else None,
    }
    sys.stdout.write(json.dumps(summary) + "\n")


# ------------------------------------------------------------------------------- the servers
@contextmanager
def ours(graph: Any) -> Iterator[str]:
    from hwbridge.viz.foxglove import start_viz

    server = start_viz(graph, port=0, topics=[TOPIC])
    try:
        yield server.url
    finally:
        server.close()


@contextmanager
def sdk(graph: Any) -> Iterator[str]:
    import foxglove

    from hwbridge.graph import ANY_TYPE

    context = foxglove.Context()
    server = foxglove.start_server(name="peer", host="127.0.0.1", port=0, context=context)
    schema = foxglove.Schema(
        name=TYPE, encoding="ros1msg", data=graph.registry.definition(TYPE).encode()
    )
    channel = foxglove.Channel(TOPIC, schema=schema, message_encoding="ros1", context=context)
    node = graph.node("bench_sdk")
    subscriber = node.subscriber(
        TOPIC, ANY_TYPE, lambda m: channel.log(m.data, log_time=time.time_ns()), raw=True
    )
    try:
        yield f"ws://127.0.0.1:{server.port}"
    finally:
        subscriber.close()
        server.stop()
        channel.close()


def measure(
    graph: Any, publisher: Any, serve: Callable[[Any], Any], rate: float | None, seconds: float
) -> dict[str, Any]:
    from hwbridge import msg

    imu = msg.new(TYPE, graph.registry)
    with serve(graph) as url:
        viewer = subprocess.Popen(
            [sys.executable, str(HERE), "--client", url, "--seconds", str(seconds)],
            stdout=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONPATH": str(HERE.parents[2])},
        )
        sent = 0
        started = time.monotonic()
        # Publish until the viewer is done (it counts `seconds` from its first message).
        while viewer.poll() is None:
            now = time.time()
            imu.header.stamp.sec = int(now)
            imu.header.stamp.nanosec = int((now % 1) * 1e9)
            publisher.publish_raw(msg.encode(imu, TYPE, graph.registry))
            sent += 1
            if rate is not None:
                wait = started + sent / rate - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
            if time.monotonic() - started > seconds + 60:
                viewer.kill()
                break
        out = viewer.communicate(timeout=30)[0] or ""
    summary = json.loads(out.splitlines()[-1]) if out.strip() else {"received": 0}
    elapsed = time.monotonic() - started
    return {
        **summary,
        "sent": sent,
        "per_s": summary["received"] / seconds,
        "sent_per_s": sent / elapsed,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--client", metavar="URL", help=argparse.SUPPRESS)
    parser.add_argument("--seconds", type=float, default=3.0)
    args = parser.parse_args()
    if args.client:
        client(args.client, args.seconds)
        return
    import socket

    from hwbridge.graph import Graph

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{port}"], domain="benchviz")
    try:
        publisher = graph.node("bench_pub").raw_publisher(TOPIC, TYPE, graph.registry.md5(TYPE))
        for case, rate in (("robot_500hz", 500.0), ("flood", None)):
            mine = measure(graph, publisher, ours, rate, args.seconds)
            theirs = measure(graph, publisher, sdk, rate, args.seconds)
            emit(
                "viz",
                {"case": case, "type": TYPE},
                mine["per_s"],
                "foxglove-sdk start_server",
                theirs["per_s"],
                hwbridge_p50_ms=mine["p50_ms"],
                hwbridge_p99_ms=mine["p99_ms"],
                peer_p50_ms=theirs["p50_ms"],
                peer_p99_ms=theirs["p99_ms"],
                hwbridge_delivered=round(mine["received"] / (rate * args.seconds), 3)
                if rate
                else None,
                peer_delivered=round(theirs["received"] / (rate * args.seconds), 3)
                if rate
                else None,
                published_per_s=[round(mine["sent_per_s"]), round(theirs["sent_per_s"])],
            )
    finally:
        graph.close()


if __name__ == "__main__":
    main()
