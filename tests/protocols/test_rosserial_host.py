"""RosserialHost against the RosserialDevice emulation over a simulated link and virtual clock.

No mocks: both ends are the real state machines; the "link" hands each side's bytes to the other
every simulated 10 ms, optionally dropping or corrupting them.
"""

from __future__ import annotations

import json
import random
import struct
from collections.abc import Callable
from typing import Any

import pytest

from hwbridge import msg
from hwbridge.protocols.base import (
    BoardSession,
    Connected,
    DebugOutput,
    Disconnected,
    EntryKind,
    Error,
    Event,
    Log,
    Message,
    ParamRequest,
    ServiceRequest,
    ServiceResponse,
)
from hwbridge.protocols.errors import (
    HwBridgeError,
    HwBridgeTimeoutError,
    ProtocolError,
    ProtocolMismatchError,
    SerializationError,
)
from hwbridge.protocols.rosserial.device import (
    Configured,
    DeviceEvent,
    Endpoint,
    ParamResult,
    Received,
    RosserialDevice,
    ServiceCalled,
    ServiceEndpoint,
    ServiceResult,
    TimeSynced,
    Unconfigured,
)
from hwbridge.protocols.rosserial.framing import encode_frame
from hwbridge.protocols.rosserial.host import (
    OLD_FIRMWARE_MESSAGE,
    REQUEST_TOPICS,
    TX_STOP,
    MessageTooLargeError,
    RosserialHost,
    TopicTable,
)

REG = msg.registry()
WALL0 = 1_700_000_000.0
DT = 0.01


def string(text: str) -> bytes:
    return msg.encode(msg.from_dict("std_msgs/String", {"data": text}))


def set_bool_response(success: bool, message: str) -> bytes:
    value = {"success": success, "message": message}
    return msg.encode(msg.from_dict("std_srvs/SetBoolResponse", value))


def toggle(request: bytes) -> bytes:
    """A device SetBool handler: answers success=data, message 'on'/'off'."""
    on = msg.decode(request, "std_srvs/SetBoolRequest").data
    return set_bool_response(bool(on), "on" if on else "off")


def board(**overrides: Any) -> RosserialDevice:
    """A typical sketch: chatter publisher, led subscriber, a SetBool server, a Trigger client."""
    options: dict[str, Any] = {
        "publishers": [Endpoint("chatter", "std_msgs/String")],
        "subscribers": [Endpoint("led", "std_msgs/Bool")],
        "service_servers": [ServiceEndpoint("toggle_led", "std_srvs/SetBool", toggle)],
        "service_clients": [ServiceEndpoint("trigger", "std_srvs/Trigger")],
    }
    options.update(overrides)
    return RosserialDevice(REG, **options)


class Sim:
    """Host and device joined by a link that delivers every DT seconds of virtual time."""

    def __init__(self, device: RosserialDevice | None, **host_options: Any) -> None:
        self.steps = 0
        self.device = device
        self.host = RosserialHost(REG, now=0.0, wall_clock=self.wall, **host_options)
        self.host_events: list[tuple[float, Event]] = []
        self.device_events: list[tuple[float, DeviceEvent]] = []
        self.link_up = True
        self.mangle: Callable[[bytes], bytes] = lambda data: data
        self.to_device_log = bytearray()

    @property
    def t(self) -> float:
        return self.steps * DT

    def wall(self) -> float:
        return WALL0 + self.t

    def step(self) -> None:
        self.steps += 1
        now = self.t
        events = self.host.tick(now)
        out = self.host.data_to_send()
        self.to_device_log += out
        if self.device is not None:
            delivered = self.mangle(out) if self.link_up else b""
            self.device_events += [(now, e) for e in self.device.receive_data(delivered, now)]
            back = self.device.data_to_send()
            events += self.host.receive_data(self.mangle(back) if self.link_up else b"", now)
        self.host_events += [(now, e) for e in events]

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / DT)):
            self.step()

    def run_until(self, predicate: Callable[[], bool], limit: float = 60.0) -> None:
        end = self.steps + round(limit / DT)
        while not predicate():
            assert self.steps < end, f"condition not met within {limit} s of virtual time"
            self.step()

    def host_of(self, kind: type[Any]) -> list[Any]:
        return [e for _, e in self.host_events if isinstance(e, kind)]

    def device_of(self, kind: type[Any]) -> list[Any]:
        return [e for _, e in self.device_events if isinstance(e, kind)]

    def connect(self) -> Connected:
        self.run_until(lambda: bool(self.host_of(Connected)), limit=10)
        return self.host_of(Connected)[-1]  # type: ignore[no-any-return]

    @property
    def table(self) -> TopicTable:
        table = self.host.topics
        assert table is not None
        return table

    def sub(self, name: str) -> int:
        """The channel of the device's subscriber ``name``."""
        return self.table.subscribers[name].topic_id

    def pub(self, name: str) -> int:
        return self.table.publishers[name].topic_id

    def server(self, name: str) -> int:
        return self.table.service_servers[name].request_topic_id

    def client(self, name: str) -> int:
        return self.table.service_clients[name].request_topic_id

    def take(self) -> list[Event]:
        """Host events so far, forgetting them."""
        events = [e for _, e in self.host_events]
        self.host_events.clear()
        return events


def connected_sim(device: RosserialDevice | None = None, **host_options: Any) -> Sim:
    sim = Sim(device if device is not None else board(), **host_options)
    sim.connect()
    sim.take()
    sim.device_events.clear()
    return sim


# ---------------------------------------------------------------------------------- start-up
def _check(h: RosserialHost) -> BoardSession:
    """RosserialHost implements the runtime's BoardSession (checked by mypy, not run)."""
    return h


def test_negotiation() -> None:
    sim = Sim(board())
    assert sim.host.state == "negotiating", "'request topics' is queued at once"
    connected = sim.connect()
    assert sim.to_device_log == REQUEST_TOPICS + sim.to_device_log[8:]
    assert sim.device_of(Configured) == [Configured()]
    (at,) = [t for t, e in sim.host_events if isinstance(e, Connected)]
    assert at <= DT + 0.5 + DT  # the first step's round trip plus the settle time
    assert sim.host.stats.topic_requests == 1, "an answered request is not repeated"
    table = sim.table
    assert set(table.publishers) == {"chatter"}
    assert table.publishers["chatter"].type == "std_msgs/String"
    assert table.publishers["chatter"].topic_id == 125
    assert table.subscribers["led"].topic_id == 100
    server = table.service_servers["toggle_led"]
    assert (server.type, server.request_topic_id, server.response_topic_id) == (
        "std_srvs/SetBool",
        101,
        126,
    )
    assert server.request_md5 == REG.service("std_srvs/SetBool").request.md5
    assert server.md5 == REG.service("std_srvs/SetBool").md5
    client = table.service_clients["trigger"]
    assert (client.request_topic_id, client.response_topic_id) == (127, 102)
    assert client.response_md5 == REG.service("std_srvs/Trigger").response.md5
    by_name = {e.name: e for e in connected.endpoints}
    assert len(connected.endpoints) == 4
    assert (by_name["chatter"].kind, by_name["chatter"].channel) == (EntryKind.PUBLISHER, 125)
    assert by_name["chatter"].md5 == REG.md5("std_msgs/String")
    assert (by_name["led"].kind, by_name["led"].channel) == (EntryKind.SUBSCRIBER, 100)
    assert by_name["led"].type_name == "std_msgs/Bool"
    toggle_ep = by_name["toggle_led"]
    assert (toggle_ep.kind, toggle_ep.channel) == (EntryKind.SERVICE_SERVER, 101)
    assert toggle_ep.md5 == REG.service("std_srvs/SetBool").md5 and toggle_ep.is_service
    trigger_ep = by_name["trigger"]
    assert (trigger_ep.kind, trigger_ep.channel) == (EntryKind.SERVICE_CLIENT, 127)
    assert trigger_ep.type_name == "std_srvs/Trigger"
    assert (connected.board_name, connected.resumed) == ("", False)
    assert sim.host.state == "connected" and sim.host.connected
    assert not sim.host_of(Error)
    assert sim.host.counters().sessions == 1


def test_connected_at_once_when_the_device_publishes() -> None:
    sim = Sim(board())
    sim.run(0.1)
    sim.device.publish("chatter", string("first"))  # type: ignore[union-attr]
    sim.step()
    events = sim.take()
    assert [type(e) for e in events] == [Connected, Message]
    assert events[1] == Message(125, string("first"), 0)


def test_board_without_topics_connects_with_an_empty_table() -> None:
    sim = Sim(RosserialDevice(REG))
    connected = sim.connect()
    assert connected.endpoints == ()
    assert sim.table.publishers == {} and sim.table.service_servers == {}


def test_request_is_repeated_with_backoff_until_answered() -> None:
    sim = Sim(None, sync_timeout=15.0)
    sim.run(16.0)
    log = bytes(sim.to_device_log)
    assert log == REQUEST_TOPICS * (len(log) // len(REQUEST_TOPICS))
    # at 0, then 0.1, 0.2, 0.4, 0.8 s apart, then every second: 0.1 0.3 0.7 1.5 2.5 ... 15.5
    assert sim.host.stats.topic_requests == 1 + 4 + 14
    (error,) = sim.host_of(Error)
    assert isinstance(error.error, HwBridgeTimeoutError)
    assert "no answer" in str(error.error) and "57600" in str(error.error)
    sim.run(15.0)
    assert len(sim.host_of(Error)) == 2, "reported again every sync_timeout"
    assert not sim.host.connected


def test_request_times() -> None:
    host = RosserialHost(REG, now=0.0)
    assert host.data_to_send() == REQUEST_TOPICS
    sent = [0.0]
    now = 0.0
    while now < 5.0:
        deadline = host.next_deadline()
        assert deadline is not None
        now = deadline
        host.tick(now)
        if host.data_to_send() == REQUEST_TOPICS:
            sent.append(round(now, 6))
    assert sent[:8] == [0.0, 0.1, 0.3, 0.7, 1.5, 2.5, 3.5, 4.5]


def test_a_board_that_starts_late_is_caught_soon() -> None:
    sim = Sim(None)
    sim.run(1.5)  # the bootloader: nothing answers
    sim.device = board()
    sim.run_until(lambda: bool(sim.device_of(Configured)), limit=2)
    assert sim.t <= 1.5 + 1.0 + 2 * DT, "the next request comes within a second"
    sim.connect()


def test_start_delay_keeps_the_host_silent_but_answers_time_requests() -> None:
    host = RosserialHost(REG, now=10.0, wall_offset=100.0, start_delay=2.0)
    assert host.state == "waiting"
    assert host.next_deadline() == 12.0
    assert host.tick(11.0) == [] and host.data_to_send() == b""
    assert host.receive_data(encode_frame(10, bytes(8)), 11.5) == []
    assert host.data_to_send() == encode_frame(10, struct.pack("<II", 111, 500_000_000))
    host.tick(12.0)
    assert host.data_to_send() == REQUEST_TOPICS
    assert host.next_deadline() == pytest.approx(12.1)


def test_md5_mismatch_refuses_only_that_topic() -> None:
    wrong = "0123456789abcdef0123456789abcdef"
    device = board(
        publishers=[
            Endpoint("chatter", "std_msgs/String"),
            Endpoint("bad", "std_msgs/Int32", wrong),
        ]
    )
    sim = Sim(device)
    sim.connect()
    (error,) = sim.host_of(Error)
    assert isinstance(error.error, ProtocolMismatchError)
    text = str(error.error)
    for part in ("'bad'", "std_msgs/Int32", wrong, REG.md5("std_msgs/Int32"), "126"):
        assert part in text
    assert set(sim.table.publishers) == {"chatter"}
    # the other topics keep working; frames on the refused one are dropped and counted
    device.publish("bad", bytes(4))
    device.publish("chatter", string("still here"))
    sim.step()
    assert sim.host_of(Message) == [Message(125, string("still here"), 0)]
    assert sim.host.stats.refused_topic_frames == 1
    assert sim.host.counters().dropped_messages == 1
    assert sim.host.stats.topic_requests == 1, "a refused topic must not trigger renegotiation"


def test_service_half_md5_mismatch() -> None:
    wrong = "f" * 32
    device = board(
        service_servers=[
            ServiceEndpoint("toggle_led", "std_srvs/SetBool", toggle, response_md5=wrong)
        ]
    )
    sim = Sim(device)
    sim.connect()
    errors = [e.error for e in sim.host_of(Error)]
    assert isinstance(errors[0], ProtocolMismatchError)
    assert "response" in str(errors[0]) and wrong in str(errors[0])
    assert REG.service("std_srvs/SetBool").response.md5 in str(errors[0])
    # the half that remains is reported as incomplete; the service is left out
    assert any("no publisher half" in str(e) for e in errors[1:])
    assert "toggle_led" not in sim.table.service_servers
    assert "trigger" in sim.table.service_clients


def test_late_topic_info_reopens_the_negotiation() -> None:
    host = RosserialHost(REG, now=0.0, wall_clock=lambda: WALL0)
    device = board()
    device.receive_data(host.data_to_send(), 0.0)
    frames = device.data_to_send()
    cut = frames.index(b"\xff\xfe", 60)  # after the time request and the first TopicInfo
    host.receive_data(frames[:cut], 0.05)
    (first,) = host.tick(1.0)
    assert isinstance(first, Connected) and [e.name for e in first.endpoints] == ["chatter"]
    assert host.receive_data(frames[cut:], 1.1) == []
    assert host.state == "negotiating" and host.connected
    (second,) = host.tick(2.0)
    assert isinstance(second, Connected)
    assert {e.name for e in second.endpoints} == {"chatter", "led", "toggle_led", "trigger"}
    assert host.counters().sessions == 1, "a reopened negotiation is the same session"


def test_unknown_topic_id_triggers_a_new_negotiation() -> None:
    device = board()
    sim = connected_sim(device)
    late = device.advertise("late", "std_msgs/String")  # advertised after the negotiation
    device.publish("late", string("x"))
    sim.run(0.02)
    assert sim.host.stats.unknown_topic_frames == 1
    sim.run_until(lambda: bool(sim.host_of(Connected)), limit=5)
    assert "late" in {e.name for e in sim.host_of(Connected)[0].endpoints}
    device.publish("late", string("y"))
    sim.step()
    assert sim.host_of(Message)[-1] == Message(late, string("y"), 0)


# ---------------------------------------------------------------------------------- data
def test_data_both_ways() -> None:
    device = board()
    sim = connected_sim(device)
    for i in range(5):
        assert device.publish("chatter", string(f"hello {i}")) > 0
    assert sim.host.publish(sim.sub("led"), msg.encode(msg.from_dict("std_msgs/Bool", {"data": 1})))
    sim.step()
    assert sim.host_of(Message) == [Message(125, string(f"hello {i}"), 0) for i in range(5)]
    assert sim.device_of(Received) == [Received("led", b"\x01")]
    stats = sim.host.stats.as_dict()
    assert stats["messages_in"] == 5 and stats["messages_out"] == 1
    assert stats["rx_checksum_errors"] == 0
    common = sim.host.counters()
    assert common.frames_received == sim.host.stats.framing.frames >= 5
    assert common.frames_sent == sim.host.stats.tx_frames
    assert common.bytes_sent == len(sim.to_device_log)
    assert common.bad_frames == common.crc_errors == 0
    assert common.detail["messages_in"] == 5
    assert common.as_dict()["rx_frames"] == common.frames_received


def test_publish_errors() -> None:
    host = RosserialHost(REG, now=0.0)
    assert host.publish(100, b"\x01") is False, "not connected: nothing sent"
    sim = connected_sim()
    with pytest.raises(ProtocolError, match="100 \\('led'\\)"):
        sim.host.publish(999, b"\x01")
    with pytest.raises(ProtocolError, match="serves no service"):
        sim.host.call_service(999, b"", now=sim.t)
    with pytest.raises(ProtocolError):
        sim.host.publish(sim.pub("chatter"), b"")  # the device publishes it, it does not listen
    with pytest.raises(ValueError, match="positive"):
        sim.host.call_service(sim.server("toggle_led"), b"", timeout=0, now=sim.t)
    assert sim.host.respond_service(999, 1, b"") is False
    assert sim.host.data_to_send() == b""


def test_call_while_not_connected_fails_at_once() -> None:
    host = RosserialHost(REG, now=0.0)
    request_id = host.call_service(101, b"\x01", now=0.0)
    (failed,) = host.tick(0.0)
    assert isinstance(failed, ServiceResponse) and failed.request_id == request_id
    assert failed.channel == 101 and not failed.ok and "not connected" in str(failed.error)


def test_oversize_is_refused_before_sending() -> None:
    device = board(input_size=280, output_size=280)  # an ATmega328P build
    sim = connected_sim(device)
    assert sim.table.subscribers["led"].buffer_size == 280
    with pytest.raises(MessageTooLargeError, match="280"):
        sim.host.publish(sim.sub("led"), bytes(281))
    with pytest.raises(MessageTooLargeError):
        sim.host.call_service(sim.server("toggle_led"), bytes(281), now=sim.t)
    assert sim.host.data_to_send() == b"", "nothing may be sent for a refused frame"
    assert sim.host.publish(sim.sub("led"), bytes(280))
    sim.step()
    assert sim.device_of(Received) == [Received("led", bytes(280))]
    assert device.stats.input_overruns == 0
    device.request_param("names", sim.t)
    sim.step()
    (asked,) = sim.host_of(ParamRequest)
    with pytest.raises(MessageTooLargeError):
        sim.host.answer_param(asked.request_id, ["x" * 100] * 3)
    assert sim.host.answer_param(asked.request_id, ["x" * 100] * 2)
    sim.step()
    assert sim.device_of(ParamResult)[0].strings == ("x" * 100, "x" * 100)


def test_debug_output_is_passed_on() -> None:
    sim = connected_sim()
    events = sim.host.receive_data(b"free ram: 812\r\n" + encode_frame(125, string("a")), sim.t)
    assert events == [DebugOutput(b"free ram: 812\r\n"), Message(125, string("a"), 0)]


# ---------------------------------------------------------------------------------- services
def test_device_service_server_calls_are_queued_one_at_a_time() -> None:
    device = board()
    sim = connected_sim(device)
    channel = sim.server("toggle_led")
    on = msg.encode(msg.from_dict("std_srvs/SetBoolRequest", {"data": True}))
    off = msg.encode(msg.from_dict("std_srvs/SetBoolRequest", {"data": False}))
    first = sim.host.call_service(channel, on, now=sim.t)
    second = sim.host.call_service(channel, off, now=sim.t)
    assert first != second
    third = sim.host.call_service(channel, on, now=sim.t)
    sim.step()
    assert sim.device_of(ServiceCalled) == [ServiceCalled("toggle_led", on)], "one at a time"
    assert sim.to_device_log.endswith(encode_frame(101, on))
    sim.run(0.05)
    assert sim.host_of(ServiceResponse)[:2] == [
        ServiceResponse(channel, first, set_bool_response(True, "on")),
        ServiceResponse(channel, second, set_bool_response(False, "off")),
    ]
    assert sim.host_of(ServiceResponse)[2].request_id == third
    assert [e.request for e in sim.device_of(ServiceCalled)] == [on, off, on]


def test_service_timeout_never_hangs() -> None:
    answers = iter([None, set_bool_response(True, "late but fine")])
    device = board(
        service_servers=[ServiceEndpoint("toggle_led", "std_srvs/SetBool", lambda r: next(answers))]
    )
    sim = connected_sim(device)
    channel = sim.server("toggle_led")
    lost = sim.host.call_service(channel, b"\x01", now=sim.t, timeout=1.0)
    queued = sim.host.call_service(channel, b"\x00", now=sim.t, timeout=5.0)
    sim.run(0.9)
    assert not sim.host_of(ServiceResponse)
    sim.run(0.2)
    failed = sim.host_of(ServiceResponse)[0]
    assert failed.request_id == lost and failed.channel == channel and failed.payload == b""
    assert isinstance(failed.error, HwBridgeTimeoutError) and isinstance(failed.error, TimeoutError)
    assert "toggle_led" in str(failed.error)
    sim.run(0.1)  # the queued call goes out once the first one has failed
    assert sim.host_of(ServiceResponse)[1:] == [
        ServiceResponse(channel, queued, set_bool_response(True, "late but fine"))
    ]
    assert sim.host.stats.service_timeouts == 1


def test_late_response_after_timeout_is_dropped() -> None:
    sim = connected_sim()
    host, now = sim.host, sim.t
    call = host.call_service(101, b"\x01", now=now, timeout=0.5)
    host.data_to_send()
    (failed,) = host.tick(now + 0.6)
    assert isinstance(failed, ServiceResponse) and failed.request_id == call and not failed.ok
    assert host.receive_data(encode_frame(126, set_bool_response(True, "on")), now + 0.7) == []
    assert host.stats.late_service_responses == 1


def test_device_service_client() -> None:
    device = board()
    sim = connected_sim(device)
    channel = sim.client("trigger")
    assert sim.host.respond_service(channel, 1, b"") is False, "no request waiting"
    assert device.call_service("trigger", b"")
    sim.step()
    (request,) = sim.host_of(ServiceRequest)
    assert (request.channel, request.payload) == (channel, b"")
    answer = msg.encode(
        msg.from_dict("std_srvs/TriggerResponse", {"success": True, "message": "ok"})
    )
    assert sim.host.respond_service(channel, request.request_id + 1, answer) is False
    assert sim.host.respond_service(channel, request.request_id, answer)
    assert sim.host.respond_service(channel, request.request_id, answer) is False, "answered"
    sim.step()
    assert sim.device_of(ServiceResult) == [ServiceResult("trigger", answer)]


def test_device_service_client_requests_get_their_own_ids() -> None:
    """A board that reset mid-call asks again: each request has an id; any can be answered."""
    sim = connected_sim()
    channel, response_id = sim.client("trigger"), 102
    requests = sim.host.receive_data(encode_frame(channel, b"") * 3, sim.t)
    ids = [r.request_id for r in requests if isinstance(r, ServiceRequest)]
    assert len(set(ids)) == 3 and 0 not in ids
    assert sim.host.respond_service(channel, ids[1], b"\x01")
    assert sim.host.respond_service(channel, ids[0], b"\x02")
    assert sim.host.respond_service(channel, ids[1], b"\x03") is False
    assert sim.host.data_to_send() == encode_frame(response_id, b"\x01") + encode_frame(
        response_id, b"\x02"
    )


def test_a_device_call_cannot_be_failed() -> None:
    device = board()
    sim = connected_sim(device)
    channel = sim.client("trigger")
    device.call_service("trigger", b"")
    sim.step()
    (request,) = sim.host_of(ServiceRequest)
    assert sim.host.respond_service(channel, request.request_id, error="no such service") is False
    assert sim.host.data_to_send() == b"", "rosserial has no way to say so"
    assert sim.host.respond_service(channel, request.request_id, b"") is False, "forgotten"


# ---------------------------------------------------------------------------------- params
PARAM_CASES: list[tuple[Any, tuple[Any, Any, Any]]] = [
    (42, ((42,), (), ())),
    ([1, -2, 3], ((1, -2, 3), (), ())),
    (True, ((1,), (), ())),
    ([True, False], ((1, 0), (), ())),
    (0.5, ((), (0.5,), ())),
    ([0.25, -1.5], ((), (0.25, -1.5), ())),
    ([1, 2.5], ((), (1.0, 2.5), ())),
    ("base_link", ((), (), ("base_link",))),
    (["a", "bé"], ((), (), ("a", "bé"))),
    (None, ((), (), ())),
    ([], ((), (), ())),
]


@pytest.mark.parametrize(("value", "arrays"), PARAM_CASES, ids=repr)
def test_param_exchange(value: Any, arrays: tuple[Any, Any, Any]) -> None:
    device = board()
    sim = connected_sim(device)
    device.request_param("p", sim.t)
    sim.step()
    (asked,) = sim.host_of(ParamRequest)
    assert asked == ParamRequest(asked.request_id, "p", False)
    assert sim.host.answer_param(asked.request_id, value)
    sim.step()
    assert sim.device_of(ParamResult) == [ParamResult("p", True, *arrays)]
    assert not sim.host_of(Log), "an answered request must not time out on the device"


@pytest.mark.parametrize(("value", "arrays"), PARAM_CASES, ids=repr)
def test_param_encoding_matches_the_registry(value: Any, arrays: tuple[Any, Any, Any]) -> None:
    """The hand-written encoder gives the bytes the generic serializer gives."""
    ints, floats, strings = arrays
    fields = {"ints": list(ints), "floats": list(floats), "strings": list(strings)}
    expected = msg.encode(msg.from_dict("rosserial_msgs/RequestParamResponse", fields))
    assert RosserialHost.encode_param("p", value) == expected


def test_param_errors_and_device_timeout() -> None:
    device = board()
    sim = connected_sim(device)
    assert sim.host.answer_param(1, 1) is False, "no request waiting"
    device.request_param("p", sim.t)
    sim.step()
    (asked,) = sim.host_of(ParamRequest)
    cases: list[tuple[Any, str]] = [
        ({"a": 1}, "dict"),
        ([1, "a"], "mix"),
        (2**31, "int32"),
        (1e39, "float32"),
    ]
    for bad, match in cases:
        with pytest.raises(SerializationError, match=match):
            sim.host.answer_param(asked.request_id, bad)
    assert sim.host.data_to_send() == b""
    assert sim.host.push_param("p", 1) is False, "rosserial cannot push parameters"
    sim.run(1.1)  # unanswered: the library gives up after 1 s and says so
    assert sim.device_of(ParamResult) == [ParamResult("p", False)]
    assert Log(2, "Failed to get param: timeout expired") in sim.host_of(Log)


# ---------------------------------------------------------------------------------- logs, time
def test_logs_every_level() -> None:
    device = board()
    sim = connected_sim(device)
    for level in range(5):
        device.log(level, f"level {level}")
    sim.step()
    assert sim.host_of(Log) == [Log(level, f"level {level}") for level in range(5)]


def test_time_sync_is_answered() -> None:
    device = board()
    sim = connected_sim(device)
    before = sim.host.stats.time_syncs
    sim.run(10.0)
    synced = sim.device_of(TimeSynced)
    assert len(synced) == 4  # every 2.5 s
    assert sim.host.stats.time_syncs - before == 4
    sec, nsec = device.ros_time(sim.t)
    assert abs(sec + nsec / 1e9 - sim.wall()) < 0.03  # the device adds the whole round trip
    assert device.configured and not sim.host_of(Disconnected)


def test_lost_sync_and_renegotiation() -> None:
    device = board()
    sim = connected_sim(device)
    sim.link_up = False
    sim.run(11.5)
    assert sim.device_of(Unconfigured) == [Unconfigured("sync_timeout")]
    sim.run_until(lambda: bool(sim.host_of(Disconnected)), limit=10)
    (lost,) = sim.host_of(Disconnected)
    assert lost.reason.startswith("no time request for ")
    assert 15.0 <= float(lost.reason.split()[4]) < 17.6
    assert isinstance(lost.error, HwBridgeTimeoutError)
    assert not sim.host.connected
    assert sim.host.publish(100, b"\x01") is False
    sim.link_up = True  # the requests sent since were lost; the host keeps asking
    sim.run_until(lambda: bool(sim.host_of(Connected)), limit=3)
    assert device.configured
    device.publish("chatter", string("back"))
    sim.step()
    assert sim.host_of(Message)[-1] == Message(125, string("back"), 0)
    assert sim.host.counters().sessions == 2


def test_device_gone_during_renegotiation_is_lost_sync() -> None:
    device = board()
    sim = connected_sim(device)
    device.advertise("late", "std_msgs/String")
    device.publish("late", string("x"))
    sim.run_until(lambda: sim.host.state == "negotiating", limit=2)
    sim.link_up = False  # the host asked for topics again, but the board is gone
    assert sim.host.connected
    sim.run_until(lambda: bool(sim.host_of(Disconnected)), limit=16)
    assert not sim.host.connected


def test_lost_sync_fails_pending_calls_first() -> None:
    device = board(service_servers=[ServiceEndpoint("toggle_led", "std_srvs/SetBool", None)])
    sim = connected_sim(device)
    call = sim.host.call_service(sim.server("toggle_led"), b"\x01", now=sim.t, timeout=60.0)
    sim.link_up = False
    sim.run_until(lambda: bool(sim.host_of(Disconnected)), limit=20)
    events = [e for e in sim.take() if isinstance(e, ServiceResponse | Disconnected)]
    assert [type(e) for e in events] == [ServiceResponse, Disconnected]
    failed = events[0]
    assert isinstance(failed, ServiceResponse)
    assert failed.request_id == call and "lost sync" in str(failed.error)


def test_device_reset_is_recovered_within_four_seconds() -> None:
    """ros_lib asks for the time every ~2.5 s and falls silent after a reset until asked for
    its topics: the host asks once the device has been silent for 3 s, long before the 15 s
    sync timeout (issue 19 item 9)."""
    device = board()
    sim = connected_sim(device)
    device.reset()
    reset_at = sim.t
    assert device.publish("chatter", string("x")) == 0  # dropped: not configured
    sim.run_until(lambda: bool(sim.host_of(Connected)) and device.configured, limit=20)
    assert sim.t - reset_at < 4.0
    assert sim.host.stats.silence_probes >= 1
    assert device.publish("chatter", string("back")) > 0
    assert not sim.host_of(Disconnected)  # the table came back before the sync timeout


def test_a_healthy_device_is_never_probed_or_renegotiated() -> None:
    device = board()
    sim = connected_sim(device)
    sim.run(600.0)  # ten minutes of virtual time, the device asking for the time as it does
    assert sim.host.stats.silence_probes == 0
    assert sim.host.stats.topic_requests == 1  # the first one only
    assert not sim.host_of(Disconnected) and not sim.host_of(Connected)


def test_without_silence_probes_a_reset_waits_for_the_sync_timeout() -> None:
    device = board()
    sim = connected_sim(device, probe_after=0)
    device.reset()
    reset_at = sim.t
    sim.run_until(lambda: bool(sim.host_of(Connected)), limit=30)
    assert sim.host_of(Disconnected)
    assert sim.t - reset_at > 10.0


def test_close_sends_tx_stop_and_fails_pending_calls() -> None:
    device = board(service_servers=[ServiceEndpoint("toggle_led", "std_srvs/SetBool", None)])
    sim = connected_sim(device)
    call = sim.host.call_service(sim.server("toggle_led"), b"\x01", now=sim.t)
    events = sim.host.close(sim.t)
    assert [type(e) for e in events] == [ServiceResponse, Disconnected]
    assert isinstance(events[0], ServiceResponse) and events[0].request_id == call
    chunks = sim.host.chunks_to_send()
    assert len(chunks) == 1 and chunks[0].endswith(TX_STOP)
    device_events = device.receive_data(chunks[0], sim.t)
    assert Unconfigured("tx_stop") in device_events
    assert device.publish("chatter", string("x")) == 0
    assert device.stats.dropped_unconfigured == 1
    assert sim.host.tick(sim.t + 100) == []
    assert sim.host.next_deadline() is None
    assert sim.host.receive_data(encode_frame(125, string("x")), sim.t) == []
    assert sim.host.close(sim.t) == []
    assert sim.host.chunks_to_send() == []
    assert sim.host.state == "closed" and not sim.host.connected
    assert sim.host.publish(sim.sub("led"), b"\x01") is False
    later = sim.host.call_service(101, b"", now=sim.t)
    (refused,) = sim.host.tick(sim.t)
    assert isinstance(refused, ServiceResponse) and refused.request_id == later
    assert "closed" in str(refused.error)


def test_describe() -> None:
    sim = connected_sim(board(input_size=280))
    facts = sim.host.describe()
    assert facts["state"] == "connected" and facts["input_buffer"] == 280
    assert (facts["publishers"], facts["subscribers"]) == (1, 1)
    assert (facts["service_servers"], facts["service_clients"]) == (1, 1)
    json.dumps(facts)
    json.dumps(sim.host.counters().as_dict())


# ---------------------------------------------------------------------------------- robustness
def test_old_firmware_is_reported_once() -> None:
    host = RosserialHost(REG, now=0.0)
    v1_time_request = b"\xff\xff\x0a\x00\x08\x00" + bytes(8) + b"\xeb"
    assert not [e for e in host.receive_data(v1_time_request, 0.01) if isinstance(e, Error)]
    errors = [e for e in host.receive_data(v1_time_request * 3, 0.02) if isinstance(e, Error)]
    assert len(errors) == 1
    assert isinstance(errors[0].error, ProtocolMismatchError)
    assert str(errors[0].error) == OLD_FIRMWARE_MESSAGE
    assert "old rosserial firmware (protocol v1, pre-hydro): update rosserial_arduino" in str(
        errors[0].error
    )


def test_single_ff_ff_glitch_is_not_old_firmware() -> None:
    sim = connected_sim()
    events = sim.host.receive_data(b"\xff\xff\x12" + encode_frame(125, string("a")), sim.t)
    assert not [e for e in events if isinstance(e, Error)]
    events = sim.host.receive_data(b"\xff\xff\x12", sim.t)
    assert not [e for e in events if isinstance(e, Error)]


def test_noisy_link_never_raises_and_recovers() -> None:
    rng = random.Random(1234)

    def noise(data: bytes) -> bytes:
        out = bytearray(data)
        for i in range(len(out)):
            if rng.random() < 0.002:
                out[i] = rng.randrange(256)
        if rng.random() < 0.01:
            out += bytes(rng.randrange(256) for _ in range(rng.randrange(20)))
        return bytes(out)

    device = board()
    sim = connected_sim(device)
    sim.mangle = noise
    received = 0
    for i in range(300):
        device.publish("chatter", string(f"message number {i}"))
        sim.run(0.05)
        received = len(sim.host_of(Message))
    sim.mangle = lambda data: data
    sim.run(20.0)  # whatever state the noise left, the session comes back
    device.publish("chatter", string("clean"))
    sim.step()
    assert sim.host_of(Message)[-1] == Message(125, string("clean"), 0)
    stats = sim.host.stats.as_dict()
    assert stats["rx_checksum_errors"] + stats["rx_length_checksum_errors"] > 0
    assert sim.host.counters().crc_errors > 0
    assert 200 < received <= 300
    for _, event in sim.host_events:
        if isinstance(event, Error):
            assert isinstance(event.error, HwBridgeError)


def test_next_deadline() -> None:
    host = RosserialHost(REG, now=10.0)
    assert host.next_deadline() == pytest.approx(10.1)
    host.tick(10.1)
    assert host.next_deadline() == pytest.approx(10.3)
    sim = connected_sim()
    deadline = sim.host.next_deadline()
    assert deadline is not None and sim.t < deadline <= sim.t + 15.0
    sim.host.call_service(sim.server("toggle_led"), b"\x01", now=sim.t, timeout=0.25)
    assert sim.host.next_deadline() == pytest.approx(sim.t + 0.25)
