"""SHORT_CALLS (PROTOCOL.md 2.8): when both ends have it and SERVICE_CHANNELS, a call on a
service's channel has a one-byte head. A request is ``request_id u8`` (1..127, bit 7 reserved)
then the body; an OK response ``request_id u8`` then the body; any other status sets the id's
bit 7 and follows it with ``status u8``.

Real sessions talk to each other over ``lossy.SimLink``, or to the scripted peer of
``test_native_service_channels`` for what no session sends. The expected bytes are written out
here from PROTOCOL.md's layout, not taken from the session's encoders.
"""

from __future__ import annotations

import itertools
import struct
from collections.abc import Callable

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hwbridge.protocols.errors import HwBridgeTimeoutError, ProtocolError
from hwbridge.protocols.native import control as ctl
from hwbridge.protocols.native.control import ALL_FEATURES, Features, ServiceStatus
from hwbridge.protocols.native.session import (
    RETIRED_ID_HOLD,
    DeviceConfig,
    DeviceSession,
    HostConfig,
    HostSession,
    ServiceRequest,
    ServiceResponse,
    SessionError,
)
from tests.protocols.lossy import SimLink
from tests.protocols.test_native_service_channels import (
    LOSSY_MAX,
    Scripted,
    answer_on,
    both_answered,
    call_both_ways,
    calls_end_once_each,
    lossy_calls,
    lossy_link,
    ref_cut,
    reliable_messages,
    scripted_board,
    scripted_host,
    serve_and_call_channels,
    service_control_messages,
)
from tests.protocols.test_native_session import (
    CH_CHATTER,
    CH_CMD,
    CH_GET_TIME,
    CH_RESET,
    connect,
    errors,
    make_link,
    of_type,
)
from tests.strategies import bounded

OK, ERROR, NO_SERVICE = 0, 1, 2
"""The status bytes of PROTOCOL.md 2.8."""
WITHOUT_SHORT = ALL_FEATURES & ~Features.SHORT_CALLS
"""An end built before SHORT_CALLS (SERVICE_CHANNELS alone)."""


def ref_request(request_id: int, body: bytes) -> bytes:
    """A request on its service's channel in a SHORT_CALLS session."""
    return bytes([request_id]) + body


def ref_response(request_id: int, status: int, body: bytes) -> bytes:
    """A response on its service's channel in a SHORT_CALLS session."""
    if status == OK:
        return bytes([request_id]) + body
    return bytes([request_id | 0x80, status]) + body


def short_board() -> Scripted:
    """A real host and a scripted board, both with SHORT_CALLS, CONNECTED."""
    return scripted_board(HostConfig().features, ALL_FEATURES)


def short_host() -> Scripted:
    """A real board and a scripted host, both with SHORT_CALLS, CONNECTED."""
    return scripted_host(ALL_FEATURES, DeviceConfig().features)


def short_peer(role: str) -> Scripted:
    return short_board() if role == "board" else short_host()


def answered(link: SimLink, calls: int = 1) -> Callable[[], bool]:
    """A ``run`` condition: the host has this many responses."""
    return lambda: len(of_type(link.host_events, ServiceResponse)) >= calls


def test_the_defaults_negotiate_short_calls() -> None:
    for features in (HostConfig().features, DeviceConfig().features):
        assert features & Features.SHORT_CALLS and features & Features.SERVICE_CHANNELS
    link = make_link(40)
    connect(link)
    for end in (link.host, link.device):
        assert end.link is not None and end.link.features & Features.SHORT_CALLS
    # what 'hwbridge board info' shows of the session: the features both ends have
    assert link.host.describe()["features"] == [
        "TIME_SYNC",
        "PARAM_PUSH",
        "ACK_IN_DATA",
        "SERVICE_CHANNELS",
        "SHORT_CALLS",
    ]


def test_calls_go_with_one_byte_heads_both_ways() -> None:
    """The host calls the board's server and the board the host's: each request is its id and
    body on the service's channel, each OK response its id and body; nothing on channel 0."""
    link = make_link(41)
    connect(link)
    to_board, to_host = call_both_ways(link)
    h2d, d2h = reliable_messages(link.h2d_log), reliable_messages(link.d2h_log)
    assert [m for m in h2d if m[0] in (CH_RESET, CH_GET_TIME)] == [
        (CH_RESET, ref_request(to_board, b"ping")),
        (CH_GET_TIME, ref_response(to_host, OK, b"ttime?")),
    ]
    assert [m for m in d2h if m[0] in (CH_RESET, CH_GET_TIME)] == [
        (CH_GET_TIME, ref_request(to_host, b"time?")),
        (CH_RESET, ref_response(to_board, OK, b"rping")),
    ]
    assert service_control_messages(link.h2d_log) == []
    assert service_control_messages(link.d2h_log) == []
    assert link.host.stats.protocol_errors == link.device.stats.protocol_errors == 0


def test_a_call_takes_three_bytes_less_on_the_wire() -> None:
    """The same Trigger-like call, with and without SHORT_CALLS on the board: the request one
    byte shorter on the line, the OK response two."""
    sizes = []
    for seed, features in ((42, ALL_FEATURES), (43, WITHOUT_SHORT)):
        link = make_link(seed, dev_cfg=DeviceConfig(features=features & DeviceConfig().features))
        connect(link)
        answer_on(link, "board", lambda p: b"\x01\x05\x00\x00\x00hello")
        link.host_events.clear()
        h2d, d2h = len(b"".join(link.h2d_log)), len(b"".join(link.d2h_log))
        link.host.call_service(CH_RESET, b"")
        link.flush()
        assert link.run(1.0, until=answered(link))
        sizes.append((len(b"".join(link.h2d_log)) - h2d, len(b"".join(link.d2h_log)) - d2h))
    (short_up, short_down), (long_up, long_down) = sizes
    assert (long_up - short_up, long_down - short_down) == (1, 2)


def test_request_ids_stay_within_1_to_127() -> None:
    """300 calls one after the other: every id the host draws is 1..127, the ids go round
    (127 is followed by 1), and every answer reaches its call."""
    link = make_link(44)
    connect(link)
    answer_on(link, "board", lambda p: p)
    ids = []
    for n in range(300):
        body = n.to_bytes(2, "little")
        ids.append(link.host.call_service(CH_RESET, body))
        link.flush()
        assert link.run(1.0, until=answered(link, n + 1))
        answer = of_type(link.host_events, ServiceResponse)[-1]
        assert (answer.request_id, answer.payload, answer.ok) == (ids[-1], body, True)
    assert set(ids) == set(range(1, 128))
    assert all(b == a % 127 + 1 for a, b in itertools.pairwise(ids))
    sent = [m for c, m in reliable_messages(link.h2d_log) if c == CH_RESET]
    assert [m[0] for m in sent] == ids


@pytest.mark.parametrize("caller", ["host", "board"])
def test_127_pending_calls_use_every_id_and_the_next_is_refused(caller: str) -> None:
    """With 127 calls pending (the scripted peer acknowledges them but answers none) no id is
    free: the next call raises, saying so; an answer frees its id for the next call."""
    peer = short_board() if caller == "host" else short_host()
    end = peer.end
    _, calls = serve_and_call_channels(peer)
    ids = []
    for _ in range(127):
        ids.append(end.call_service(calls, b""))
        peer.read()
    assert sorted(ids) == list(range(1, 128))
    with pytest.raises(SessionError, match="127 requests are pending"):
        end.call_service(calls, b"")
    events = peer.write(peer.reliable(calls, ref_response(ids[40], OK, b"a")))
    (answer,) = of_type(events, ServiceResponse)
    assert (answer.request_id, answer.payload) == (ids[40], b"a")
    assert end.call_service(calls, b"again") == ids[40]
    peer.read()
    assert peer.sent(calls)[-1] == ref_request(ids[40], b"again")


@pytest.mark.parametrize("freed_by", ["its late answer", "the hold's end"])
def test_the_id_of_a_call_that_timed_out_waits_for_its_late_answer(freed_by: str) -> None:
    """With 127 ids a late answer could meet a newer call that drew its id: the id of a call
    that timed out is not drawn again until its late answer came (which is ignored) or
    RETIRED_ID_HOLD passed, and a caller with every other id pending is told why."""
    peer = short_board()
    end = peer.end
    _, calls = serve_and_call_channels(peer)
    first = end.call_service(calls, b"", timeout=0.5)
    peer.read()
    peer.now += 1.0
    (timed_out,) = of_type(end.tick(peer.now), ServiceResponse)
    assert timed_out.request_id == first and isinstance(timed_out.error, HwBridgeTimeoutError)
    ids = []
    for _ in range(126):
        ids.append(end.call_service(calls, b"", timeout=1000.0))
        peer.read()
    assert sorted([first, *ids]) == list(range(1, 128))
    with pytest.raises(SessionError, match="1 that timed out are held for their late answers"):
        end.call_service(calls, b"")
    if freed_by == "its late answer":
        events = peer.write(peer.reliable(calls, ref_response(first, OK, b"late")))
        assert not of_type(events, ServiceResponse)  # taken for no call
    else:
        steps = int(RETIRED_ID_HOLD / 0.2) + 1
        for _ in range(steps):  # the link kept alive, the id held all along
            peer.write(peer.best_effort(0, ctl.HeartbeatMsg().encode()))
            peer.now += 0.2
            end.tick(peer.now)
        assert end.connected
    assert end.call_service(calls, b"", timeout=1000.0) == first
    assert end.stats.protocol_errors == 0


@pytest.mark.parametrize("peer_role", ["board", "host"])
def test_error_and_no_service_answers_set_bit_7_and_carry_the_status(peer_role: str) -> None:
    """The real end answers ERROR with id | 0x80, the status and the text; a request on a
    channel it serves but has not connected yet gets NO_SERVICE the same way; and it reads such
    answers to its own calls."""
    peer = short_peer(peer_role)
    end = peer.end
    serves, calls = serve_and_call_channels(peer)
    (call,) = of_type(peer.write(peer.reliable(serves, ref_request(9, b"x"))), ServiceRequest)
    assert call.request_id == 9
    assert end.respond_service(serves, 9, error="broken")
    peer.read()
    assert peer.sent(serves)[-1] == ref_response(9, ERROR, b"broken")
    for status, what in ((ERROR, "failed: nope"), (NO_SERVICE, "does not serve it")):
        request_id = end.call_service(calls, b"")
        peer.read()
        events = peer.write(peer.reliable(calls, ref_response(request_id, status, b"nope")))
        (answer,) = of_type(events, ServiceResponse)
        assert answer.request_id == request_id and answer.payload == b""
        assert isinstance(answer.error, SessionError) and what in str(answer.error)
    # OK written out with its status byte (bit 7 set) is OK too
    request_id = end.call_service(calls, b"")
    peer.read()
    events = peer.write(peer.reliable(calls, bytes([request_id | 0x80, OK]) + b"fine"))
    (answer,) = of_type(events, ServiceResponse)
    assert (answer.request_id, answer.payload, answer.ok) == (request_id, b"fine", True)
    assert end.stats.protocol_errors == 0


@pytest.mark.parametrize("server", ["board", "host"])
def test_a_request_before_the_server_is_connected_gets_a_short_no_service(server: str) -> None:
    if server == "board":
        peer = scripted_host(ALL_FEATURES, DeviceConfig().features, ready=False)
        channel = CH_RESET
    else:
        peer = scripted_board(HostConfig().features, ALL_FEATURES, table_end=False)
        channel = CH_GET_TIME
    peer.write(peer.reliable(channel, ref_request(0x45, b"early")))
    assert peer.sent(channel) == [ref_response(0x45, NO_SERVICE, b"")]
    assert not of_type(peer.events, ServiceRequest)
    assert peer.service_controls() == []


def test_an_error_text_is_cut_to_fill_the_callers_max_message() -> None:
    """An ERROR answer's head is two bytes (id | 0x80, status): its text is cut on a character
    boundary so that the response is exactly the caller's max_message."""
    host_max, device_max = 40, DeviceConfig().max_message
    link = make_link(45, host_cfg=HostConfig(max_message=host_max))
    connect(link)
    answer_on(link, "board", lambda p: "é" * 40)  # 80 bytes: cut to 38, on a boundary
    answer_on(link, "host", lambda p: "x" + "é" * 40)  # 81 bytes: cut to 62 splits a character
    to_board = link.host.call_service(CH_RESET, b"")
    to_host = link.device.call_service(CH_GET_TIME, b"")
    link.flush()
    assert link.run(2.0, until=both_answered(link))
    board_cut = ref_cut("é" * 40, host_max - 2)
    host_cut = ref_cut("x" + "é" * 40, device_max - 2)
    assert len(board_cut) == host_max - 2 and len(host_cut) == device_max - 3
    (answer,) = of_type(link.host_events, ServiceResponse)
    assert str(answer.error).endswith(f"failed: {board_cut.decode()}")
    (answer,) = of_type(link.device_events, ServiceResponse)
    assert str(answer.error).endswith(f"failed: {host_cut.decode()}")
    sent = (CH_RESET, ref_response(to_board, ERROR, board_cut))
    assert len(sent[1]) == host_max and sent in reliable_messages(link.d2h_log)
    assert (CH_GET_TIME, ref_response(to_host, ERROR, host_cut)) in reliable_messages(link.h2d_log)
    assert link.host.stats.dropped_messages == link.device.stats.dropped_messages == 0


def test_bodies_up_to_the_peers_max_message() -> None:
    """A request's and an OK response's body may be one byte short of the receiver's
    max_message; a byte more is refused by the sender."""
    host_max, device_max = 100, 64
    link = make_link(
        46,
        host_cfg=HostConfig(max_message=host_max),
        dev_cfg=DeviceConfig(max_message=device_max),
    )
    connect(link)
    with pytest.raises(SessionError, match=f"at most {device_max} bytes"):
        link.host.call_service(CH_RESET, bytes(device_max))
    with pytest.raises(SessionError, match=f"at most {host_max} bytes"):
        link.device.call_service(CH_GET_TIME, bytes(host_max))
    answer_on(link, "board", lambda p: bytes(range(host_max - 1)))
    answer_on(link, "host", lambda p: bytes(device_max - 1))
    link.host.call_service(CH_RESET, bytes(range(device_max - 1)))
    link.device.call_service(CH_GET_TIME, bytes(host_max - 1))
    link.flush()
    assert link.run(2.0, until=both_answered(link))
    (up,) = of_type(link.host_events, ServiceResponse)
    (down,) = of_type(link.device_events, ServiceResponse)
    assert up.ok and up.payload == bytes(range(host_max - 1))
    assert down.ok and down.payload == bytes(device_max - 1)
    (request,) = of_type(link.device_events, ServiceRequest)
    assert request.payload == bytes(range(device_max - 1))
    for end in (link.host, link.device):
        assert end.stats.oversize_messages == 0 and end.stats.protocol_errors == 0


@pytest.mark.parametrize("peer_role", ["board", "host"])
def test_malformed_short_messages_are_protocol_errors(peer_role: str) -> None:
    """An empty request, an empty response, a response with bit 7 set and no status byte, and
    one with a status PROTOCOL.md does not define: each reported, counted and dropped; the
    pending call still takes its real answer, and bit 7 of a request's id is ignored."""
    peer = short_peer(peer_role)
    end = peer.end
    serves, calls = serve_and_call_channels(peer)
    request_id = end.call_service(calls, b"q")
    peer.read()
    assert peer.sent(calls) == [ref_request(request_id, b"q")]
    bad = [
        peer.reliable(serves, b""),
        peer.reliable(calls, b""),
        peer.reliable(calls, bytes([request_id | 0x80])),
        peer.reliable(calls, bytes([request_id | 0x80, 3]) + b"x"),
    ]
    for i, frame in enumerate(bad, start=1):
        events = peer.write(frame)
        assert end.stats.protocol_errors == i
        (error,) = errors(events)
        assert isinstance(error, ProtocolError) and f"channel {frame.channel}" in str(error)
        assert not of_type(events, ServiceResponse) and not of_type(events, ServiceRequest)
    assert "too short" in str(errors(peer.events)[0])
    assert "unknown status 3" in str(errors(peer.events)[-1])
    # an empty message on a topic this end sends is on the wrong channel, not a short call
    wrong = CH_CMD if peer_role == "board" else CH_CHATTER
    (error,) = errors(peer.write(peer.reliable(wrong, b"")))
    assert "too short" not in str(error) and f"channel {wrong}" in str(error)
    assert end.stats.protocol_errors == len(bad) + 1
    events = peer.write(peer.reliable(calls, ref_response(request_id, OK, b"a")))
    (answer,) = of_type(events, ServiceResponse)
    assert (answer.request_id, answer.payload, answer.ok) == (request_id, b"a", True)
    events = peer.write(peer.reliable(serves, bytes([0x80 | 77]) + b"next"))
    (call,) = of_type(events, ServiceRequest)
    assert (call.channel, call.request_id, call.payload) == (serves, 77, b"next")
    assert end.respond_service(serves, 77, b"done")
    peer.read()
    assert peer.sent(serves)[-1] == ref_response(77, OK, b"done")
    assert end.connected and peer.service_controls() == []


@pytest.mark.parametrize("peer_role", ["board", "host"])
def test_an_old_form_request_is_answered_short_when_its_id_fits(peer_role: str) -> None:
    """A SERVICE_REQUEST that comes all the same, which no end sends in such a session: with an
    id of 1..127 it is served and answered on the channel in the short form; with a larger id,
    which the short answer cannot carry, it gets NO_SERVICE as a SERVICE_RESPONSE on channel 0
    (the caller's clear error, not a timeout)."""
    peer = short_peer(peer_role)
    end = peer.end
    serves, _ = serve_and_call_channels(peer)
    events = peer.write(peer.control(ctl.ServiceRequestMsg(serves, 100, b"old")))
    (call,) = of_type(events, ServiceRequest)
    assert (call.channel, call.request_id, call.payload) == (serves, 100, b"old")
    assert end.respond_service(serves, 100, b"new")
    peer.read()
    assert peer.sent(serves) == [ref_response(100, OK, b"new")]
    events = peer.write(peer.control(ctl.ServiceRequestMsg(serves, 300, b"old")))
    assert not of_type(events, ServiceRequest) and errors(events) == []
    peer.read()
    assert peer.service_controls() == [
        ctl.ServiceResponseMsg(serves, 300, ServiceStatus.NO_SERVICE, b"").encode()
    ]
    assert peer.sent(serves) == [ref_response(100, OK, b"new")]
    assert end.connected


@pytest.mark.parametrize(
    ("host_features", "device_features"),
    [
        (HostConfig().features, DeviceConfig().features & WITHOUT_SHORT),
        (WITHOUT_SHORT, DeviceConfig().features),
    ],
    ids=["new host, SERVICE_CHANNELS board", "SERVICE_CHANNELS host, new board"],
)
def test_with_one_end_without_short_calls_the_heads_are_those_of_service_channels(
    host_features: Features, device_features: Features
) -> None:
    link = make_link(
        47,
        host_cfg=HostConfig(features=host_features),
        dev_cfg=DeviceConfig(features=device_features),
    )
    connect(link)
    assert link.host.link is not None and not link.host.link.features & Features.SHORT_CALLS
    answer_on(link, "board", lambda p: b"r" + p)
    answer_on(link, "host", lambda p: "no")
    to_board = link.host.call_service(CH_RESET, b"ping")
    to_host = link.device.call_service(CH_GET_TIME, b"?")
    link.flush()
    assert link.run(2.0, until=both_answered(link))
    h2d, d2h = reliable_messages(link.h2d_log), reliable_messages(link.d2h_log)
    assert [m for m in h2d if m[0] in (CH_RESET, CH_GET_TIME)] == [
        (CH_RESET, struct.pack("<H", to_board) + b"ping"),
        (CH_GET_TIME, struct.pack("<HB", to_host, ERROR) + b"no"),
    ]
    assert [m for m in d2h if m[0] in (CH_RESET, CH_GET_TIME)] == [
        (CH_GET_TIME, struct.pack("<H", to_host) + b"?"),
        (CH_RESET, struct.pack("<HB", to_board, OK) + b"rping"),
    ]


def test_short_calls_without_service_channels_change_nothing() -> None:
    """A board with SHORT_CALLS but not SERVICE_CHANNELS: calls go as SERVICE_REQUEST and
    SERVICE_RESPONSE on channel 0, their ids in 16 bits as always."""
    features = DeviceConfig().features & ~Features.SERVICE_CHANNELS
    link = make_link(48, dev_cfg=DeviceConfig(features=features))
    connect(link)
    answer_on(link, "board", lambda p: b"r" + p)
    to_board = link.host.call_service(CH_RESET, b"ping")
    link.flush()
    assert link.run(2.0, until=lambda: bool(of_type(link.host_events, ServiceResponse)))
    assert service_control_messages(link.h2d_log) == [
        struct.pack("<BBH", 0x20, CH_RESET, to_board) + b"ping"
    ]
    assert service_control_messages(link.d2h_log) == [
        struct.pack("<BBHB", 0x21, CH_RESET, to_board, OK) + b"rping"
    ]


# ---------------------------------------------------------------------------------------------
# properties

_bodies = st.binary(max_size=40)


@pytest.mark.parametrize("peer_role", ["board", "host"])
@bounded(60)
@given(
    calls=st.lists(
        st.tuples(st.integers(0, 255), _bodies, st.sampled_from([OK, ERROR])), max_size=6
    ),
    answers=st.lists(
        st.tuples(_bodies, st.sampled_from([OK, ERROR, NO_SERVICE]), st.booleans()), max_size=6
    ),
)
def test_any_id_and_body_round_trips_in_the_short_form(
    peer_role: str,
    calls: list[tuple[int, bytes, int]],
    answers: list[tuple[bytes, int, bool]],
) -> None:
    """The real end serves any request byte and body the peer sends (the id is its low 7
    bits) and answers with that id; its own calls go out as id and body, and take any answer:
    OK short or with its status byte written out, ERROR with its text, NO_SERVICE."""
    peer = short_peer(peer_role)
    end = peer.end
    serves, calls_on = serve_and_call_channels(peer)
    for head, body, status in calls:
        events = peer.write(peer.reliable(serves, bytes([head]) + body))
        (call,) = of_type(events, ServiceRequest)
        assert (call.channel, call.request_id, call.payload) == (serves, head & 0x7F, body)
        reply = body[::-1]
        if status == OK:
            assert end.respond_service(serves, call.request_id, reply)
        else:
            reply = reply.decode("utf-8", errors="replace").encode()
            assert end.respond_service(serves, call.request_id, error=reply.decode())
        peer.read()
        assert peer.sent(serves)[-1] == ref_response(call.request_id, status, reply)
    for body, status, explicit in answers:
        request_id = end.call_service(calls_on, body)
        assert 1 <= request_id <= 127
        peer.read()
        assert peer.sent(calls_on)[-1] == ref_request(request_id, body)
        reply = body[::-1]
        if status == OK and explicit:
            message = bytes([request_id | 0x80, OK]) + reply
        else:
            message = ref_response(request_id, status, reply)
        (answer,) = of_type(peer.write(peer.reliable(calls_on, message)), ServiceResponse)
        assert answer.request_id == request_id
        if status == OK:
            assert answer.ok and answer.payload == reply
        else:
            assert isinstance(answer.error, SessionError) and answer.payload == b""
    assert peer.service_controls() == []
    assert end.stats.protocol_errors == 0


@bounded(20)
@lossy_calls
def test_short_calls_over_a_lossy_duplicating_link_end_once_each(
    seed: int, loss: float, duplicate: float, reorder: float, window: int, data: st.DataObject
) -> None:
    """1, 5, 40 or 127 calls each way at once (127: every id of an end pending together),
    bodies up to 40 bytes, answered OK (up to the caller's max_message, after the one-byte
    head) or ERROR, over a link that loses, corrupts, duplicates and reorders: each call ends
    with exactly one response, its own."""
    host_max, device_max = LOSSY_MAX
    link = lossy_link(make_link, seed, (loss, duplicate, reorder), window, 8192)
    sizes = st.integers(0, 40)
    body = sizes.flatmap(lambda n: st.binary(min_size=n, max_size=n))
    count = data.draw(st.sampled_from([1, 5, 40, 127]), label="calls each way")
    host_bodies = data.draw(st.lists(body, min_size=count, max_size=count))
    board_bodies = data.draw(st.lists(body, min_size=count, max_size=count))
    host_ids, board_ids = calls_end_once_each(
        link, host_bodies, board_bodies, (host_max - 1, device_max - 1), 900.0
    )
    assert len(set(host_ids)) == len(set(board_ids)) == count  # every id a different one
    assert all(1 <= i <= 127 for i in [*host_ids, *board_ids])


def test_no_topic_channel_is_taken_for_a_call() -> None:
    """A reliable message on a topic channel in a SHORT_CALLS session is a topic message (or a
    message on the wrong channel), never read as a short call."""
    link = make_link(49)
    connect(link)
    assert isinstance(link.device, DeviceSession) and isinstance(link.host, HostSession)
    assert link.device.publish(CH_CHATTER, b"\x05abc")
    link.flush()
    assert link.run(1.0, until=lambda: bool(link.host_events))
    assert not of_type(link.host_events, ServiceRequest)
    assert not of_type(link.host_events, ServiceResponse)
