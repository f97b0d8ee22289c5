#!/usr/bin/env python3
"""Start-up benchmark: ``hwbridge connect URL`` launched -> a board's first message arriving at a
subscriber in another process.

Three processes per run, as a user has them:

- a *board* (this script with ``--board``): a device-side protocol session, native or rosserial,
  on a fresh pty (reachable at a symlink), publishing ``std_msgs/String`` on ``chatter`` every
  10 ms from the moment it is powered (what it sends before the host has set it up is dropped,
  by the board or by the host, as on a real link);
- a *subscriber* (this script with ``--subscriber``): a graph node started before the bridge.
  The bridge is the graph's router, so there is nothing to attach to yet: the node's Zenoh
  client retries its connect every 10 ms (Zenoh's own retry, ``connect/timeout_ms: -1``) and
  declares its subscriber once connected, as a node started before the bridge would. It writes
  the ``time.monotonic()`` of the first message's arrival (CLOCK_MONOTONIC: one clock for every
  process on the machine);
- the *bridge*: ``hwbridge --domain D connect --listen E PTY`` (protocol detected, as by
  default), launched by this script at a ``time.monotonic()`` it notes just before.

``hwbridge_s`` is the median over ``--runs`` of arrival minus launch; ``goal_s`` the target
(1.0 s native, 1.2 s rosserial). ``import_s`` is the import time of the connect command's path
up to the first message: one extra run of the bridge under ``python -X importtime``, summing
the top-level imports from ``hwbridge`` on (importtime's own overhead included, so a little
high). ``peer`` would be rosserial_python's ``serial_node.py``; it is not packaged for this
machine (Debian has ``python3-rospy`` and ``ros-core`` but no rosserial), so ``peer`` is null.

Prints one JSON object per line (one per protocol), like the other benchmarks.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import stop_process

GOALS = {"native": 1.0, "rosserial": 1.2}
DOMAIN = "startup_bench"
TOPIC = "/chatter"
PUBLISH_PERIOD = 0.01
WAIT_S = 30.0
"""Longest wait for a run's first message before the run counts as failed."""


# ---------------------------------------------------------------------------------- the board
def board_main(protocol: str, path: str) -> None:
    """Board process: a device session on a pty at ``path``, publishing chatter every 10 ms."""
    from hwbridge import msg
    from hwbridge.links import open_link
    from hwbridge.pump import SessionPump

    registry = msg.registry()
    payload = msg.encode(msg.new("std_msgs/String", data="hello"))
    session: Any
    if protocol == "native":
        from hwbridge.protocols.native import session as ns
        from hwbridge.protocols.native.control import EntryKind

        session = ns.DeviceSession(
            ns.BoardInfo("bench", b"\x01", "1"),
            [
                ns.TopicEntry(
                    1,
                    EntryKind.PUBLISHER,
                    "chatter",
                    "std_msgs/String",
                    registry.md5("std_msgs/String"),
                )
            ],
        )

        def publish(device: Any) -> object:
            return device.publish(1, payload)

    else:
        from hwbridge.protocols.rosserial import RosserialDevice

        session = RosserialDevice(registry)
        session.advertise("chatter", "std_msgs/String")

        def publish(device: Any) -> object:
            return device.publish("chatter", payload)

    link = open_link(f"pty://?symlink={path}")
    pump = SessionPump(link, session, lambda _event: None, name="bench-board")
    pump.start()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    print("ready", flush=True)
    while not stop.wait(PUBLISH_PERIOD):
        try:
            pump.call(publish)
        except Exception:  # noqa: BLE001 - the host may be gone between runs; keep powered
            continue
    pump.stop()
    link.close()


# ----------------------------------------------------------------------------- the subscriber
def subscriber_main(endpoint: str, topic: str) -> None:
    """Subscriber process: a client that waits for the bridge, then for one message."""
    from hwbridge.graph import ANY_TYPE, Graph, GraphConfig

    config = GraphConfig(
        mode="client",
        connect=(endpoint,),
        domain=DOMAIN,
        extra={
            "connect/timeout_ms": "-1",
            "connect/retry": json.dumps(
                {"period_init_ms": 10, "period_max_ms": 10, "period_increase_factor": 1}
            ),
        },
    )
    arrived = threading.Event()
    stamp: list[float] = []

    def on_message(_message: object) -> None:
        if not stamp:
            stamp.append(time.monotonic())
            arrived.set()

    print("ready", flush=True)  # imports done; now waiting for the bridge in Zenoh's connect
    with Graph(config) as graph:
        connected = time.monotonic()
        graph.node("startup_bench").subscriber(topic, ANY_TYPE, on_message, raw=True)
        if arrived.wait(WAIT_S):
            print(json.dumps({"arrived": stamp[0], "connected": connected}), flush=True)


# ------------------------------------------------------------------------------- the harness
def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def _python_command(*argv: str) -> list[str]:
    return [sys.executable, str(Path(__file__).resolve()), *argv]


def _hwbridge_command() -> list[str]:
    """The installed console script next to this interpreter, else ``python -m hwbridge``."""
    script = Path(sys.executable).with_name("hwbridge")
    return [str(script)] if script.exists() else [sys.executable, "-m", "hwbridge"]


def _wait_line(process: subprocess.Popen[str], what: str) -> str:
    assert process.stdout is not None
    line = process.stdout.readline()
    if not line:
        raise RuntimeError(f"{what} exited before it was ready (status {process.wait()})")
    return line.strip()


def one_run(protocol: str, workdir: Path, importtime: bool = False) -> dict[str, Any]:
    """One launch of the bridge; returns launch -> first message (and the bridge's stderr)."""
    pty_path = workdir / f"board-{protocol}-{time.monotonic_ns()}"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    board = subprocess.Popen(
        _python_command("--board", protocol, str(pty_path)), stdout=subprocess.PIPE, text=True
    )
    subscriber = subprocess.Popen(
        _python_command("--subscriber", endpoint, TOPIC), stdout=subprocess.PIPE, text=True
    )
    bridge: subprocess.Popen[str] | None = None
    log = (workdir / f"{pty_path.name}.log").open("w+")  # not a pipe: importtime fills one
    try:
        _wait_line(board, "the board")
        _wait_line(subscriber, "the subscriber")
        time.sleep(0.2)  # let both settle into their waits
        command = _hwbridge_command()
        if importtime:
            command = [sys.executable, "-X", "importtime", "-m", "hwbridge"]
        env = dict(os.environ, HWBRIDGE_DOMAIN=DOMAIN)
        env.pop("HWBRIDGE_ENDPOINT", None)
        env.pop("HWBRIDGE_ZENOH_CONFIG", None)
        launched = time.monotonic()
        bridge = subprocess.Popen(
            [*command, "connect", "--listen", endpoint, str(pty_path)],
            stdout=subprocess.DEVNULL,
            stderr=log,
            text=True,
            env=env,
        )
        out = subscriber.stdout
        assert out is not None
        result: dict[str, Any] = {}
        reader = threading.Thread(
            target=lambda: result.update(json.loads(out.readline() or "{}")), daemon=True
        )
        reader.start()
        reader.join(WAIT_S + 5)
        if "arrived" not in result:
            log.seek(0)
            raise RuntimeError(
                f"{protocol}: no message at the subscriber within {WAIT_S:g} s; the bridge "
                f"said:\n{log.read()[-2000:]}"
            )
        stop_process(bridge, signal.SIGINT)
        log.seek(0)
        return {
            "seconds": result["arrived"] - launched,
            "connected_s": result["connected"] - launched,
            "stderr": log.read(),
        }
    finally:
        for process in (bridge, subscriber, board):
            if process is not None:
                stop_process(process)
        for process in (board, subscriber):
            if process.stdout is not None:
                process.stdout.close()
        log.close()


def import_seconds(importtime_stderr: str) -> float:
    """Sum of the top-level cumulative import times from the first ``hwbridge`` import on."""
    total_us = 0
    counting = False
    for line in importtime_stderr.splitlines():
        if not line.startswith("import time:") or "|" not in line:
            continue
        _, cumulative, name = line[len("import time:") :].split("|", 2)
        if not cumulative.strip().isdigit() or name.startswith("  "):
            continue  # the header, or a nested import (counted in its parent's cumulative)
        counting = counting or name.strip().startswith("hwbridge")
        if counting:
            total_us += int(cumulative)
    return total_us / 1e6


def bench(protocol: str, runs: int, workdir: Path) -> dict[str, Any]:
    times = [one_run(protocol, workdir) for _ in range(runs)]
    traced = one_run(protocol, workdir, importtime=True)
    ours = statistics.median(t["seconds"] for t in times)
    return {
        "bench": f"startup_{protocol}_pty",
        "hwbridge_s": round(ours, 3),
        "goal_s": GOALS[protocol],
        "import_s": round(import_seconds(traced["stderr"]), 3),
        "peer": None,
        "peer_s": None,
        "ratio": None,
        "runs": runs,
        "min_s": round(min(t["seconds"] for t in times), 3),
        "max_s": round(max(t["seconds"] for t in times), 3),
        "subscriber_connected_s": round(statistics.median(t["connected_s"] for t in times), 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="launches per protocol (median)")
    parser.add_argument("--protocol", choices=["native", "rosserial", "both"], default="both")
    parser.add_argument("--board", nargs=2, metavar=("PROTOCOL", "PATH"), help=argparse.SUPPRESS)
    parser.add_argument(
        "--subscriber", nargs=2, metavar=("ENDPOINT", "TOPIC"), help=argparse.SUPPRESS
    )
    args = parser.parse_args()
    if args.board:
        board_main(*args.board)
        return
    if args.subscriber:
        subscriber_main(*args.subscriber)
        return
    protocols = ["native", "rosserial"] if args.protocol == "both" else [args.protocol]
    with tempfile.TemporaryDirectory(prefix="hwbridge-startup-") as tmp:
        for protocol in protocols:
            line = bench(protocol, max(1, args.runs), Path(tmp))
            sys.stdout.write(json.dumps(line) + "\n")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
