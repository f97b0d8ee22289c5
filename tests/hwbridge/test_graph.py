"""The Zenoh graph with real sessions: a router (embedded) and clients (attached)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge import msg
from hwbridge.errors import HwBridgeError, HwBridgeTimeoutError, ProtocolMismatchError
from hwbridge.graph import (
    ANY_TYPE,
    DeferredReply,
    Graph,
    GraphNameError,
    ParamError,
    ParamServer,
    RawMessage,
    ServiceError,
    resolve_name,
)
from hwbridge.graph.names import decode_segment, encode_segment
from tests.netutil import call_when_ready, free_port, wait_until


def test_names() -> None:
    assert resolve_name("odom", "/robot1") == "/robot1/odom"
    assert resolve_name("/odom", "/robot1") == "/odom"
    assert resolve_name("~rate", "/robot1", "driver") == "/robot1/driver/rate"
    for bad in ("", "/a//b", "/a/", "/1abc", "/a-b", "a b"):
        with pytest.raises(GraphNameError):
            resolve_name(bad)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.text())
def test_key_segment_round_trip(text: str) -> None:
    segment = encode_segment(text)
    assert segment and not set(segment) & set("/*$?#")
    assert decode_segment(segment) == text


def test_typed_publish_subscribe_across_sessions(router: Graph, client: Graph) -> None:
    got: list[Any] = []
    client.node("listener").subscriber("/chatter", "std_msgs/String", got.append)
    pub = router.node("talker").publisher("chatter", "std_msgs/String")
    assert wait_until(lambda: _published_until(pub, {"data": "hi"}, lambda: bool(got)))
    assert got[0].data == "hi"


def _published_until(pub: Any, message: Any, done: Any) -> bool:
    """Publish until the subscriber has seen one (declarations propagate asynchronously)."""
    if not done():
        pub.publish(message)
    return bool(done())


def test_md5_mismatch_is_a_clear_error_not_garbage(router: Graph, client: Graph) -> None:
    errors: list[HwBridgeError] = []
    delivered: list[Any] = []
    sub = client.node("wrong").subscriber(
        "/typed", "geometry_msgs/Twist", delivered.append, on_error=errors.append
    )
    pub = router.node("right").publisher("/typed", "std_msgs/String")
    assert wait_until(lambda: _published_until(pub, {"data": "x"}, lambda: bool(errors)))
    assert not delivered
    assert isinstance(errors[0], ProtocolMismatchError)
    text = str(errors[0])
    assert "std_msgs/String" in text and "geometry_msgs/Twist" in text
    assert "992ce8a1687cec8c8bd883ec73ca41d1" in text and "9f195f881246fdfa2798d1d3eebca84a" in text
    assert sub.type_mismatches >= 1


def test_raw_bytes_pass_untouched_and_any_type_decodes(router: Graph, client: Graph) -> None:
    raw: list[RawMessage] = []
    decoded: list[Any] = []
    node = client.node("spy")
    node.subscriber("/raw", ANY_TYPE, raw.append, raw=True)
    node.subscriber("/raw", ANY_TYPE, decoded.append)
    md5 = msg.md5("std_msgs/Int32")
    pub = router.node("bridge").raw_publisher("/raw", "std_msgs/Int32", md5)
    payload = (123456).to_bytes(4, "little")

    def step() -> bool:
        if not (raw and decoded):
            pub.publish_raw(payload)
        return bool(raw and decoded)

    assert wait_until(step)
    assert raw[0] == RawMessage("/raw", "std_msgs/Int32", md5, payload)
    assert decoded[0].data == 123456


def test_wait_for_message_and_timeout(router: Graph, client: Graph) -> None:
    import threading

    node = client.node("waiter")
    with pytest.raises(HwBridgeTimeoutError, match="no message on /quiet"):
        node.wait_for_message("/quiet", "std_msgs/Bool", timeout=0.3)
    pub = router.node("ticker").publisher("/tick", "std_msgs/UInt32")
    stop = threading.Event()

    def tick() -> None:
        count = 0
        while not stop.is_set():
            pub.publish({"data": count})
            count += 1
            stop.wait(0.01)

    thread = threading.Thread(target=tick)
    thread.start()
    try:
        message = node.wait_for_message("/tick", "std_msgs/UInt32", timeout=10)
    finally:
        stop.set()
        thread.join()
    assert message.data >= 0


def test_services(router: Graph, client: Graph) -> None:
    def handler(request: Any) -> dict[str, Any]:
        if request.data:
            raise RuntimeError("motor driver not ready")
        return {"success": True, "message": "disabled"}

    router.node("board").service("/enable", "std_srvs/SetBool", handler)
    node = client.node("caller")
    response = call_when_ready(node, "/enable", "std_srvs/SetBool", {"data": False})
    assert (response.success, response.message) == (True, "disabled")
    with pytest.raises(ServiceError, match="RuntimeError: motor driver not ready"):
        node.call("/enable", "std_srvs/SetBool", {"data": True}, timeout=5)
    with pytest.raises(ServiceError, match="type mismatch: caller uses std_srvs/Trigger"):
        node.call("/enable", "std_srvs/Trigger", {}, timeout=5)
    with pytest.raises(HwBridgeTimeoutError, match=r"service /nobody \(is its server running"):
        node.call("/nobody", "std_srvs/Trigger", {}, timeout=0.3)


def test_parameters(router: Graph, client: Graph) -> None:
    server = ParamServer(router, {"/robot": {"wheel": {"radius": 0.033, "count": 2}}})
    params = client.params
    updates: list[tuple[str, Any]] = []
    params.on_update(lambda name, value: updates.append((name, value)))
    assert wait_until(lambda: _try(lambda: params.get("/robot/wheel/radius")) == 0.033)
    assert params.get("/robot") == {"wheel": {"count": 2, "radius": 0.033}}
    params.set("/robot/name", "diffbot")
    params.set("/flags", [True, False])
    assert server.get("/robot/name") == "diffbot"
    assert params.names() == ["/flags", "/robot/name", "/robot/wheel/count", "/robot/wheel/radius"]
    with pytest.raises(ParamError, match="no parameter /missing"):
        params.get("/missing")
    assert params.get("/missing", None) is None
    params.delete("/robot/wheel")
    assert params.names() == ["/flags", "/robot/name"]
    with pytest.raises(ParamError, match="is not a bool"):
        params.set("/bad", object())
    assert wait_until(lambda: ("/robot/wheel/radius", None) in updates)
    assert ("/robot/name", "diffbot") in updates


def _try(action: Any) -> Any:
    try:
        return action()
    except HwBridgeError:
        return None


def test_discovery_sees_entities_come_and_go(router: Graph, client: Graph) -> None:
    events: list[tuple[str, str, bool]] = []
    client.watch(lambda e, alive: events.append((e.kind, e.name, alive)))
    node = router.node("odometry", namespace="/diffbot")
    pub = node.publisher("odom", "nav_msgs/Odometry")
    assert wait_until(lambda: ("pub", "/diffbot/odom", True) in events)
    snapshot = client.snapshot()
    assert "/diffbot/odometry" in snapshot.nodes
    assert "nav_msgs/Odometry" in snapshot.topics()["/diffbot/odom"]
    pub.close()
    assert wait_until(lambda: ("pub", "/diffbot/odom", False) in events)


def test_attaching_without_a_bridge_says_what_to_do() -> None:
    with pytest.raises(HwBridgeError, match="is a bridge running"):
        Graph.attached(connect=[f"tcp/127.0.0.1:{free_port()}"])


def test_other_process_publishes_and_exits_without_closing(
    endpoint: str, graph_domain: str, router: Graph
) -> None:
    """A second process attaches, publishes, subscribes, and exits without close(): no hang."""
    got: list[Any] = []
    router.node("sink").subscriber("/from_child", "std_msgs/String", got.append)
    script = textwrap.dedent(
        f"""
        import time
        from hwbridge.graph import Graph
        graph = Graph.attached(connect=["{endpoint}"], domain="{graph_domain}")
        node = graph.node("child")
        node.subscriber("/anything", "std_msgs/String", print)
        pub = node.publisher("/from_child", "std_msgs/String")
        for _ in range(200):
            pub.publish({{"data": "from another process"}})
            time.sleep(0.01)
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 0, done.stderr
    assert wait_until(lambda: bool(got))
    assert got[0].data == "from another process"


def test_calls_keep_a_querier_per_timeout_and_cope_with_many_timeouts(
    router: Graph, client: Graph
) -> None:
    node = client.node("caller")
    # Declared before the server exists: the first call finds nobody, later ones reach it.
    with pytest.raises(HwBridgeTimeoutError, match=r"service /late \(is its server running"):
        node.call("/late", "std_srvs/Trigger", {}, timeout=0.2)
    served = []

    def handler(_request: Any) -> dict[str, Any]:
        served.append(1)
        return {"success": True, "message": f"call {len(served)}"}

    router.node("board").service("/late", "std_srvs/Trigger", handler)
    call_when_ready(node, "/late", "std_srvs/Trigger", {})
    node.max_queriers = 3  # past the cap, calls with further timeouts make one-off gets
    answers = [
        node.call("/late", "std_srvs/Trigger", {}, timeout=2.0 + index / 10).message
        for index in range(6)
    ]
    assert answers == [f"call {len(served) - 5 + index}" for index in range(6)]
    with pytest.raises(HwBridgeTimeoutError, match=r"service /gone \(is its server running"):
        node.call("/gone", "std_srvs/Trigger", {}, timeout=0.2)  # past the cap too


def test_a_server_slower_than_the_callers_timeout_is_a_timeout_not_a_service_error(
    router: Graph, client: Graph
) -> None:
    """Zenoh ends such a call with a bare "Timeout" error reply: the caller gets
    HwBridgeTimeoutError naming the service and its timeout, as documented for call()."""
    import threading

    release = threading.Event()

    def handler(_request: bytes, reply: DeferredReply) -> None:
        def later() -> None:
            release.wait(5)
            reply.ok(b"\x01\x02\x00\x00\x00ok")

        threading.Thread(target=later).start()

    router.node("board").deferred_service("/homing", "std_srvs/Trigger", handler)
    node = client.node("caller")
    try:
        assert wait_until(lambda: "/homing" in client.snapshot(timeout=0.5).services())
        with pytest.raises(HwBridgeTimeoutError) as info:
            node.call("/homing", "std_srvs/Trigger", {}, timeout=0.3)
        assert not isinstance(info.value, ServiceError)
        assert "/homing within 0.3 s" in str(info.value)
    finally:
        release.set()
    # A server's own error text is still a ServiceError, whatever it says.
    router.node("board").deferred_service(
        "/says_timeout", "std_srvs/Trigger", lambda _r, reply: reply.error("Timeout of the arm")
    )
    with pytest.raises(ServiceError, match="Timeout of the arm"):
        call_when_ready(node, "/says_timeout", "std_srvs/Trigger", {})


def test_deferred_service_answers_from_another_thread(router: Graph, client: Graph) -> None:
    import threading

    def handler(request: bytes, reply: DeferredReply) -> None:
        def later() -> None:
            if request == b"\x01":
                reply.error("board says no")
            else:
                reply.ok(b"\x01\x02\x00\x00\x00ok")
            reply.ok(b"ignored: a call is answered once")

        threading.Thread(target=later).start()

    router.node("board").deferred_service("/later", "std_srvs/Trigger", handler)
    node = client.node("caller")
    response = call_when_ready(node, "/later", "std_srvs/Trigger", {})
    assert (response.success, response.message) == (True, "ok")
    with pytest.raises(ServiceError, match="board says no"):
        node.call_raw("/later", "std_srvs/Trigger", b"\x01", timeout=5)


def test_a_call_has_its_answer_before_the_server_lets_the_query_go(
    router: Graph, client: Graph
) -> None:
    """A server that replies and holds on to the query (a bridge replies from its pump thread,
    then lets go): the caller returns with the reply, not when Zenoh's final message comes. With
    Zenoh's default consolidation the call waited for that message (here the fallback 10 s
    later)."""
    import threading

    answer = b"\x01\x02\x00\x00\x00ok"
    held: list[Any] = []

    def serve(query: Any) -> None:
        payload = query.payload
        if payload is None or payload.to_bytes() != b"ping":
            # kept before the reply goes: the caller, answered, may look at once; its final
            # message waits for drop()
            held.append(query)
        query.reply(query.key_expr, answer, express=True)

    def answers_ping() -> bool:
        try:
            return node.call_raw("/held", "std_srvs/Trigger", b"ping", timeout=0.5) == answer
        except HwBridgeError:
            return False

    queryable = router.session.declare_queryable(router.service_key("/held"), serve)
    node = client.node("caller")
    returned = threading.Event()
    fell_back: list[bool] = []

    def let_go() -> None:
        fell_back.append(not returned.wait(10))
        for query in held:
            query.drop()

    releaser = threading.Thread(target=let_go)
    try:
        assert wait_until(answers_ping)
        releaser.start()
        assert node.call_raw("/held", "std_srvs/Trigger", b"", timeout=30) == answer
        returned.set()
        releaser.join(15)
        assert fell_back == [False]
        assert len(held) == 1
    finally:
        returned.set()
        queryable.undeclare()


def test_a_publish_after_close_from_a_callback_is_dropped_and_counted(
    router: Graph, client: Graph
) -> None:
    """A device node's subscriber callback may still run on a Zenoh thread while the node
    shuts down (``hwbridge up`` on Ctrl-C): its publish after the publisher closed is a quiet
    no-op, counted, not a ``zenoh.ZError`` out of the callback."""
    node = client.node("late_talker")
    out = node.publisher("/late/out", "std_msgs/String")
    out.close()
    assert out.closed
    escaped: list[BaseException] = []
    calls: list[int] = []

    def relay(_message: Any) -> None:
        try:
            out.publish({"data": "too late"})
        except BaseException as exc:  # noqa: BLE001 - what the test looks for
            escaped.append(exc)
        calls.append(1)

    node.subscriber("/late/in", "std_msgs/String", relay)
    feed = router.node("late_feed").publisher("/late/in", "std_msgs/String")
    assert wait_until(lambda: _published_until(feed, {"data": "go"}, lambda: bool(calls)))
    assert escaped == []
    assert out.dropped_after_close == len(calls) >= 1
    assert out.sent == 0


def test_a_publish_after_the_graph_closed_is_dropped_and_counted(endpoint: str) -> None:
    graph = Graph.attached(connect=[endpoint], domain=f"closed-{free_port()}")
    out = graph.node("orphan").publisher("/orphan/out", "std_msgs/String")
    graph.close()
    out.publish({"data": "after close"})
    out.publish_raw(b"\x00\x00\x00\x00")
    assert out.closed and out.dropped_after_close == 2 and out.sent == 0
