"""The bridge's service timeout (``hwbridge connect --service-timeout``), both protocols, both ways.

Boards are real device sessions (native and rosserial) on ptys, bridged by a real
:class:`~hwbridge.bridge.Bridge` on a real Zenoh graph. Each bridge has two boards with the same
slow service (it answers after ``SLOW`` seconds): ``quick`` with a service timeout shorter than
that, ``patient`` with a longer one. The last test runs ``hwbridge connect`` and
``hwbridge service call`` as processes.
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from hwbridge import msg
from hwbridge.bridge import DEFAULT_SERVICE_TIMEOUT, BoardSpec, Bridge
from hwbridge.bridge.adapter import SessionAdapter
from hwbridge.bridge.endpoints import PendingCalls
from hwbridge.errors import HwBridgeError
from hwbridge.graph import DeferredReply, Graph, Node
from hwbridge.protocols.native import session as ns
from hwbridge.protocols.native.control import EntryKind
from hwbridge.protocols.rosserial import RosserialDevice
from tests.boards import PtyBoard, wait_for
from tests.bridgeproc import BridgeProcess
from tests.netutil import free_port

SLOW = 1.0
"""Seconds the boards' ``slow`` service (and the graph's ``lookup`` service) take to answer."""
QUICK = 0.3
PATIENT = 3.0
TRIGGER = "std_srvs/Trigger"
SLOW_CH, MUTE_CH, LOOKUP_CH = 1, 2, 3
"""Native channels: ``slow`` (answers late), ``mute`` (never answers), ``lookup`` (a client)."""


def trigger_response(message: str) -> bytes:
    return msg.encode(msg.new("std_srvs/TriggerResponse", success=True, message=message))


def trigger_request() -> bytes:
    return msg.encode(msg.new("std_srvs/TriggerRequest"))


ANSWER = trigger_response("homed")


# ---------------------------------------------------------------------------------- boards
def native_board(name: str) -> ns.DeviceSession:
    md5 = msg.registry().service(TRIGGER).md5
    topics = [
        ns.TopicEntry(SLOW_CH, EntryKind.SERVICE_SERVER, "slow", TRIGGER, md5),
        ns.TopicEntry(MUTE_CH, EntryKind.SERVICE_SERVER, "mute", TRIGGER, md5),
        ns.TopicEntry(LOOKUP_CH, EntryKind.SERVICE_CLIENT, "lookup", TRIGGER, md5),
    ]
    # The board's own call timeout is long: a failure it sees early comes from the bridge.
    config = ns.DeviceConfig(service_timeout=30.0)
    return ns.DeviceSession(ns.BoardInfo(name, b"\x00\x02", "0.1.0"), topics, config)


def native_answer_late(board: PtyBoard, event: Any) -> None:
    """Answer ``slow`` after SLOW seconds, from another thread; ``mute`` never."""
    if not isinstance(event, ns.ServiceRequest) or event.channel != SLOW_CH:
        return
    request_id = event.request_id

    def answer() -> None:
        with contextlib.suppress(HwBridgeError):  # the test may have stopped the board
            board.pump.call(lambda s: s.respond_service(SLOW_CH, request_id, ANSWER))

    threading.Timer(SLOW, answer).start()


def rosserial_board() -> RosserialDevice:
    """A sketch whose service callback blocks, as a servo-homing callback does on a board."""
    device = RosserialDevice(msg.registry())

    def home(_request: bytes) -> bytes:
        time.sleep(SLOW)
        return ANSWER

    device.advertise_service("slow", TRIGGER, home)
    device.advertise_service("mute", TRIGGER, lambda _request: None)
    device.service_client("lookup", TRIGGER)
    return device


@dataclass
class Rig:
    """A bridge with a ``quick`` and a ``patient`` board, and a node to call services from."""

    protocol: str
    bridge: Bridge
    graph: Graph
    node: Node
    boards: dict[str, PtyBoard] = field(default_factory=dict)

    def pending(self, board: str) -> PendingCalls:
        adapter = self.bridge.boards[board].adapter
        assert isinstance(adapter, SessionAdapter), adapter
        return adapter.endpoints.pending

    def call(self, board: str, service: str, timeout: float) -> tuple[Any, float]:
        """(response or the error raised, seconds the call took)."""
        started = time.monotonic()
        try:
            result: Any = self.node.call(f"/{board}/{service}", TRIGGER, {}, timeout=timeout)
        except HwBridgeError as exc:
            result = exc
        return result, time.monotonic() - started


@pytest.fixture(params=["native", "rosserial"])
def rig(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Rig]:
    protocol = str(request.param)
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="svctimeout")
    bridge = Bridge(graph)
    rig = Rig(protocol, bridge, graph, graph.node("caller"))
    try:
        for name, timeout in (("quick", QUICK), ("patient", PATIENT)):
            path = tmp_path / f"tty{name}"
            if protocol == "native":
                board = PtyBoard(path, native_board(name), name, native_answer_late)
            else:
                board = PtyBoard(path, rosserial_board(), name)
            rig.boards[name] = board.start()
            bridge.add_board(
                BoardSpec(
                    str(path),
                    protocol=protocol,
                    namespace=f"/{name}",
                    name=name,
                    start_delay=0.1,
                    service_timeout=timeout,
                )
            )
        for name in rig.boards:
            assert wait_for(
                lambda n=name: f"/{n}/slow" in bridge.boards[n].info()["topics"].get("serves", ())
            ), bridge.boards[name].info()
        yield rig
    finally:
        bridge.stop()
        graph.close()
        for board in rig.boards.values():
            board.stop()


# ---------------------------------------------------------------------------------- option
@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf"), 1e20, "5", True])
def test_board_spec_refuses_a_bad_service_timeout(bad: Any) -> None:
    with pytest.raises(HwBridgeError, match="service timeout must be a number of seconds above 0"):
        BoardSpec("memory://x", service_timeout=bad)


def test_board_spec_service_timeout_default_and_value() -> None:
    assert DEFAULT_SERVICE_TIMEOUT == 5.0
    assert BoardSpec("memory://x").service_timeout == 5.0
    assert BoardSpec("memory://x", service_timeout=8).service_timeout == 8.0


@pytest.mark.parametrize("bad", ["0", "-2", "nan", "inf", "1e20", "soon"])
def test_connect_refuses_a_bad_service_timeout(
    capsys: pytest.CaptureFixture[str], bad: str
) -> None:
    from hwbridge.cli import main

    code = main(["connect", "memory://svc-cli", f"--service-timeout={bad}"])
    err = " ".join(capsys.readouterr().err.replace("│", " ").split())
    assert code == 2, err
    assert "Invalid value for" in err
    assert "--service-timeout" in err


def test_connect_help_lists_service_timeout(capsys: pytest.CaptureFixture[str]) -> None:
    from hwbridge.cli import main

    assert main(["connect", "--help"]) == 0
    out = capsys.readouterr().out
    assert "--service-timeout" in out
    assert "SECONDS" in out


# ---------------------------------------------------------------------------------- graph -> board
def test_graph_call_of_a_slow_board_service_obeys_the_service_timeout(rig: Rig) -> None:
    """The quick board's call fails at its 0.3 s with an error naming the service and the
    timeout; the patient board's (3 s) gets the answer the board gives after 1 s."""
    failed, took = rig.call("quick", "slow", timeout=10.0)
    assert isinstance(failed, HwBridgeError), failed
    assert QUICK * 0.9 <= took < SLOW, took
    text = str(failed)
    assert "/quick/slow" in text
    assert f"within {QUICK:g} s" in text
    assert "--service-timeout" in text

    answered, took = rig.call("patient", "slow", timeout=10.0)
    assert not isinstance(answered, Exception), answered
    assert answered.message == "homed"
    assert SLOW * 0.9 <= took < PATIENT, took


def test_timed_out_and_abandoned_calls_leave_no_pending_entry(rig: Rig) -> None:
    """Entries of the bridge's pending calls go away whether the bridge timed the call out
    (board late or mute) or the caller gave up first and the board answered after."""
    quick, patient = rig.pending("quick"), rig.pending("patient")

    # The bridge times out (0.3 s); the board's answer comes later (1 s) and is dropped.
    failed, _ = rig.call("quick", "slow", timeout=10.0)
    assert isinstance(failed, HwBridgeError)
    assert len(quick) == 0
    time.sleep(SLOW)  # the late answer arrives: nothing is waiting for it, nothing breaks
    assert len(quick) == 0

    # The caller gives up (0.1 s) before the bridge does (0.3 s); the board never answers.
    gone, _ = rig.call("quick", "mute", timeout=0.1)
    assert isinstance(gone, HwBridgeError)
    assert "did not answer within" not in str(gone)  # the caller's own timeout, not the bridge's
    assert wait_for(lambda: len(quick) == 0, QUICK + 2.0)

    # The caller gives up (0.3 s) before the board answers (1 s, within the bridge's 3 s).
    gone, _ = rig.call("patient", "slow", timeout=0.3)
    assert isinstance(gone, HwBridgeError)
    assert "did not answer within" not in str(gone)
    assert len(patient) == 1  # the bridge still waits for the board...
    assert wait_for(lambda: len(patient) == 0, SLOW + 2.0)  # ...and is done when it answers

    # The bridge still works for the next caller.
    answered, _ = rig.call("patient", "slow", timeout=10.0)
    assert not isinstance(answered, Exception), answered


# ---------------------------------------------------------------------------------- board -> graph
def serve_lookup_late(node: Node, board: str) -> None:
    """Serve ``/BOARD/lookup`` on the graph, answering after SLOW seconds."""

    def start(_request: bytes, reply: DeferredReply) -> None:
        threading.Timer(SLOW, reply.ok, (trigger_response("found"),)).start()

    node.deferred_service(f"/{board}/lookup", TRIGGER, start)


def board_calls_lookup(rig: Rig, board: str) -> Callable[[], list[Any]]:
    """Make ``board`` call its ``lookup`` client; returns a getter of the outcomes it saw."""
    device = rig.boards[board]
    if rig.protocol == "native":
        device.pump.call(lambda s: s.call_service(LOOKUP_CH, trigger_request()))
        return lambda: [e for e in device.of_type("ServiceResponse") if e.channel == LOOKUP_CH]
    assert device.pump.call(lambda s: s.call_service("lookup", trigger_request()))
    return lambda: device.of_type("ServiceResult")


def test_board_call_of_a_slow_graph_service_obeys_the_service_timeout(
    rig: Rig, caplog: pytest.LogCaptureFixture
) -> None:
    """A board's call of a graph service that takes 1 s: the quick board's bridge gives up at
    0.3 s (a native board is told why at once; rosserial cannot fail a call, so the bridge logs
    it), the patient board's gets the answer."""
    for board in rig.boards:
        serve_lookup_late(rig.graph.node(f"lookup_{board}"), board)
    caplog.set_level(logging.ERROR, logger="hwbridge.board.quick")
    started = time.monotonic()
    quick = board_calls_lookup(rig, "quick")
    patient = board_calls_lookup(rig, "patient")

    expected = f"no answer from /quick/lookup within {QUICK:g} s"
    assert wait_for(lambda: expected in caplog.text, SLOW * 3), caplog.text
    assert "--service-timeout" in caplog.text
    if rig.protocol == "native":
        assert wait_for(lambda: bool(quick()), 5.0)
        assert time.monotonic() - started < SLOW
        (outcome,) = quick()
        assert outcome.error is not None
        assert expected in str(outcome.error)

    assert wait_for(lambda: bool(patient()), SLOW + 5.0)
    (answer,) = patient()
    payload = answer.payload if rig.protocol == "native" else answer.response
    assert getattr(answer, "error", None) is None
    assert msg.decode(payload, "std_srvs/TriggerResponse").message == "found"
    if rig.protocol == "rosserial":
        assert quick() == []  # no answer for the quick board: the bridge did not make one up


# ---------------------------------------------------------------------------------- the command
@pytest.mark.parametrize("protocol", ["native", "rosserial"])
def test_connect_service_timeout_reaches_the_graph_caller(tmp_path: Path, protocol: str) -> None:
    path = tmp_path / "ttyBOARD"
    if protocol == "native":
        board = PtyBoard(path, native_board("uno"), "uno", native_answer_late)
    else:
        board = PtyBoard(path, rosserial_board(), "uno")
    bridge = BridgeProcess(
        path,
        tmp_path,
        f"svccli{protocol}",
        *("--protocol", protocol, "--namespace", "/arm", "--name", "uno"),
        *("--service-timeout", str(QUICK)),
    )
    board.start()
    try:
        bridge.wait_ready()
        assert wait_for(lambda: "connected" in bridge.output(), 30), bridge.output()
        info = bridge.cli("board", "info", "uno", "--json")
        assert info.returncode == 0, info.stderr
        assert json.loads(info.stdout)["service_timeout"] == QUICK
        call = bridge.cli("service", "call", "/arm/slow", "--timeout", "10", "--wait", "5")
        assert call.returncode == 1, call.stdout + call.stderr + bridge.output()
        error = " ".join(call.stderr.split())
        assert "/arm/slow" in error
        assert f"board uno did not answer within {QUICK:g} s" in error
        assert "--service-timeout" in error
    finally:
        assert bridge.stop() == 0, bridge.output()
        board.stop()


def test_board_call_answered_too_large_for_the_board_fails_at_once_with_the_reason(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A native board (max_message 64) calls a graph service whose answer is larger than it
    takes: the bridge cannot hand the answer on, and the board's call fails at once with the
    size limit as its reason, not at the board's own 30 s timeout."""
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="svcsize")
    bridge = Bridge(graph)
    path = tmp_path / "ttysmall"
    md5 = msg.registry().service(TRIGGER).md5
    session = ns.DeviceSession(
        ns.BoardInfo("small", b"\x00\x03", "0.1.0"),
        [ns.TopicEntry(LOOKUP_CH, EntryKind.SERVICE_CLIENT, "lookup", TRIGGER, md5)],
        ns.DeviceConfig(service_timeout=30.0, max_message=64),
    )
    board = PtyBoard(path, session, "small").start()
    caplog.set_level(logging.ERROR, logger="hwbridge.board.small")
    try:
        graph.node("lookup_small").service(
            "/small/lookup", TRIGGER, lambda _request: trigger_response("x" * 200), raw=True
        )
        bridge.add_board(BoardSpec(str(path), protocol="native", namespace="/small", name="small"))
        assert wait_for(lambda: bridge.boards["small"].state == "connected")
        started = time.monotonic()
        board.pump.call(lambda s: s.call_service(LOOKUP_CH, trigger_request()))

        def outcomes() -> list[Any]:
            return [e for e in board.of_type("ServiceResponse") if e.channel == LOOKUP_CH]

        assert wait_for(lambda: bool(outcomes()), 10.0)
        (outcome,) = outcomes()
        assert time.monotonic() - started < 10.0
        assert outcome.error is not None
        # (the reason as the board's 64 bytes take it: the size and whose limit it broke)
        # (206: the one-byte head of SHORT_CALLS and the 205 bytes of the Trigger answer)
        assert "is 206 bytes but the board accepts" in str(outcome.error), outcome.error
        assert "at most 64 bytes (its max_message)" in caplog.text
    finally:
        bridge.stop()
        graph.close()
        board.stop()
