#!/usr/bin/env python3
"""The host session's own Python per service call: native ``HostSession`` against ``RosserialHost``.

Each protocol's host session runs back to back with a device session of its protocol in this
process (no link, no thread): the host calls a std_srvs/Trigger-like service, writes the request,
the device answers "hello" (not timed), and the host reads the answer to its ServiceResponse.
Timed is the host's part alone: ``call_service`` with ``chunks_to_send``, then ``receive_data``
with ``next_deadline`` (what the bridge's pump runs per call). Each of ``--rounds`` rounds times
``--calls`` calls of one protocol, then of the other; the figures are the medians over the rounds.
Prints one JSON line: ``native_us`` and ``rosserial_us`` per call, and ``ratio`` (rosserial /
native: above 1, the native session costs less). With ``ACK_IN_DATA``, ``SERVICE_CHANNELS`` and
``SHORT_CALLS`` (the defaults) a native call is one frame each way, as on the bridge with a board.

This is the part of a call's host time that differs between the two protocols (issue 29: at
1 Mbaud the AVR boards' part is at parity, and ``sim_service_hello`` is left with the
difference). Runs in a few seconds.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

HELLO = b"\x01\x05\x00\x00\x00hello"
"""A std_srvs/Trigger response: success, then "hello"."""
TEST_HELLO = b"\x05\x00\x00\x00hello"
"""A rosserial_arduino/Test response: "hello"."""


def _exchange(host: Any, device: Any, now: float) -> None:
    host.tick(now)
    device.receive_data(host.data_to_send(), now)
    host.receive_data(device.data_to_send(), now)


def _timed(
    host: Any,
    device: Any,
    now: float,
    channel: int,
    request: bytes,
    answer: Callable[[list[Any]], None],
) -> tuple[Callable[[], float], Callable[[], bool]]:
    """One timed call of ``channel`` on a pair connected at ``now`` (``answer`` answers the
    device's events of a request), and a check that calls were answered."""
    from hwbridge.protocols.base import ServiceResponse

    clock = [now]
    answers = [0]

    def call() -> float:
        clock[0] += 0.001
        t = clock[0]
        started = time.perf_counter()
        host.call_service(channel, request, now=t)
        wire = host.chunks_to_send()
        spent = time.perf_counter() - started
        answer(device.receive_data(b"".join(wire), t))
        back = device.data_to_send()
        started = time.perf_counter()
        events = host.receive_data(back, t + 0.0005)
        host.next_deadline()
        spent += time.perf_counter() - started
        answers[0] += sum(isinstance(e, ServiceResponse) and e.ok for e in events)
        return spent

    return call, lambda: answers[0] > 0


def native_pair() -> tuple[Callable[[], float], Callable[[], bool]]:
    """A connected native host and board: (one timed call, a check it answered)."""
    from hwbridge import msg
    from hwbridge.protocols.native import session as ns
    from hwbridge.protocols.native.control import EntryKind

    md5 = msg.registry().md5("std_srvs/Trigger")
    host = ns.HostSession()
    device = ns.DeviceSession(
        ns.BoardInfo("bench", b"\x01", "1"),
        [ns.TopicEntry(1, EntryKind.SERVICE_SERVER, "/reset", "std_srvs/Trigger", md5)],
    )
    now = 0.0
    while not (host.connected and device.connected):
        now += 0.002
        if now > 10:
            raise RuntimeError("the native sessions did not connect")
        _exchange(host, device, now)

    def answer(events: list[Any]) -> None:
        for event in events:
            if isinstance(event, ns.ServiceRequest):
                device.respond_service(event.channel, event.request_id, HELLO)

    return _timed(host, device, now, 1, b"", answer)


def rosserial_pair() -> tuple[Callable[[], float], Callable[[], bool]]:
    """A connected rosserial host and device (which answers by itself): (one timed call, a check
    it answered)."""
    from hwbridge import msg
    from hwbridge.protocols.rosserial import RosserialDevice, RosserialHost

    registry = msg.registry()
    device = RosserialDevice(registry)
    device.advertise_service("test_srv", "rosserial_arduino/Test", lambda _request: TEST_HELLO)
    host = RosserialHost(registry, now=0.0)
    now = 0.0
    while not host.connected:
        now += 0.01
        if now > 10:
            raise RuntimeError("the rosserial sessions did not connect")
        _exchange(host, device, now)
    table = host.topics
    if table is None or "test_srv" not in table.service_servers:
        raise RuntimeError("the rosserial host did not take the device's service")
    channel = table.service_servers["test_srv"].request_topic_id
    return _timed(host, device, now, channel, b"\x01\x00\x00\x00x", lambda _events: None)


def measure(calls: int, rounds: int) -> dict[str, Any]:
    """The JSON line's fields: per-call medians over ``rounds`` rounds of ``calls`` calls."""
    native, native_ok = native_pair()
    rosserial, rosserial_ok = rosserial_pair()
    for _ in range(min(calls, 200)):  # warm both up
        native()
        rosserial()
    ours: list[float] = []
    theirs: list[float] = []
    for _ in range(rounds):
        ours.append(sum(native() for _ in range(calls)) / calls)
        theirs.append(sum(rosserial() for _ in range(calls)) / calls)
    if not (native_ok() and rosserial_ok()):
        raise RuntimeError("a session did not answer its calls")
    # the ratio is taken from the figures as printed, so that a reader who divides them gets it
    native_us = round(statistics.median(ours) * 1e6, 2)
    rosserial_us = round(statistics.median(theirs) * 1e6, 2)
    return {
        "bench": "session_call",
        "native_us": native_us,
        "peer": "rosserial_host",
        "rosserial_us": rosserial_us,
        "ratio": round(rosserial_us / native_us, 3),
        "native_rounds_us": [round(x * 1e6, 2) for x in ours],
        "rosserial_rounds_us": [round(x * 1e6, 2) for x in theirs],
        "calls": calls,
        "rounds": rounds,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--calls", type=int, default=5000, help="calls per round (default 5000)")
    parser.add_argument("--rounds", type=int, default=5, help="rounds (default 5)")
    args = parser.parse_args()
    if args.calls < 1 or args.rounds < 1:
        parser.error("--calls and --rounds must be at least 1")
    print(json.dumps(measure(args.calls, args.rounds)), flush=True)


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:
        sys.exit(130)
