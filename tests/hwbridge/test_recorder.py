"""Recording to MCAP and playing back, with real Zenoh sessions, files and subprocesses."""

from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.msg import get_types_from_msg

from hwbridge import msg
from hwbridge.graph import ANY_TYPE, Graph, RawMessage
from hwbridge.recorder import Player, Recorder, RecordingError
from tests.netutil import free_port, wait_until

DOMAIN = "rectest"
STRING_MD5 = "992ce8a1687cec8c8bd883ec73ca41d1"
IMU_MD5 = "6a62c6daae103f4ff57a132d6f95cec2"
UNKNOWN_MD5 = "0123456789abcdef0123456789abcdef"


@pytest.fixture(scope="module")
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture(scope="module")
def router(endpoint: str) -> Iterator[Graph]:
    graph = Graph.embedded(listen=[endpoint], domain=DOMAIN)
    yield graph
    graph.close()


@pytest.fixture
def client(router: Graph, endpoint: str) -> Iterator[Graph]:
    graph = Graph.attached(connect=[endpoint], domain=DOMAIN)
    yield graph
    graph.close()


def read_mcap(path: Path) -> tuple[Any, Any, list[tuple[Any, Any, Any]]]:
    """Header, summary and (schema, channel, message) triples, read by the official reader."""
    with path.open("rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        header = reader.get_header()
        summary = reader.get_summary()
        messages = list(reader.iter_messages())
    return header, summary, messages


def decode_with_schema(schema: Any, data: bytes) -> tuple[Any, str]:
    """Decode bytes using only the schema text (a fresh rosbags store); also its md5."""
    store_name = "/msg/".join(schema.name.split("/", 1))
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(schema.data.decode(), store_name))
    _, md5 = store.generate_msgdef(store_name)
    return store.deserialize_ros1(data, store_name), md5


def imu(seq: int) -> dict[str, Any]:
    return {
        "header": {"seq": seq, "stamp": {"secs": 10 + seq, "nsecs": 5}, "frame_id": "imu_link"},
        "orientation": {"w": 1.0},
        "linear_acceleration": {"x": 0.5 * seq, "z": 9.81},
    }


# ---------------------------------------------------------------------- recording
def test_record_typed_messages(router: Graph, client: Graph, tmp_path: Path) -> None:
    path = tmp_path / "typed.mcap"
    node = router.node("talker")
    chatter = node.publisher("/chatter", "std_msgs/String")
    imu_pub = node.publisher("/imu", "sensor_msgs/Imu")
    count = 25
    sent_strings = [msg.encode(msg.new("std_msgs/String", data=f"hello {i}")) for i in range(count)]
    sent_imu = [msg.encode(msg.from_dict("sensor_msgs/Imu", imu(i))) for i in range(count)]
    with Recorder(client, path, ["/chatter", "imu"]) as recorder:
        assert chatter.wait_for_subscribers(10) and imu_pub.wait_for_subscribers(10)
        for a, b in zip(sent_strings, sent_imu, strict=True):
            chatter.publish_raw(a)
            imu_pub.publish_raw(b)
        assert wait_until(lambda: recorder.stats.messages >= 2 * count)
    stats = recorder.stats
    assert {(c.topic, c.type, c.md5, c.messages) for c in stats.channels} == {
        ("/chatter", "std_msgs/String", STRING_MD5, count),
        ("/imu", "sensor_msgs/Imu", IMU_MD5, count),
    }
    assert stats.bytes == sum(map(len, sent_strings + sent_imu))
    chatter.close()
    imu_pub.close()

    header, summary, messages = read_mcap(path)
    assert header.profile == "ros1"
    assert summary.statistics.message_count == 2 * count
    schemas = {s.name: s for s in summary.schemas.values()}
    assert set(schemas) == {"std_msgs/String", "sensor_msgs/Imu"}
    registry = msg.registry()
    for name, schema in schemas.items():
        assert schema.encoding == "ros1msg"
        assert schema.data.decode() == registry.definition(name)
    assert "MSG: std_msgs/Header" in schemas["sensor_msgs/Imu"].data.decode()
    channels = {c.topic: c for c in summary.channels.values()}
    assert set(channels) == {"/chatter", "/imu"}
    for topic, type_name, md5 in (
        ("/chatter", "std_msgs/String", STRING_MD5),
        ("/imu", "sensor_msgs/Imu", IMU_MD5),
    ):
        channel = channels[topic]
        assert channel.message_encoding == "ros1"
        assert channel.metadata == {"md5sum": md5, "type": type_name}
        assert summary.schemas[channel.schema_id].name == type_name

    by_topic: dict[str, list[Any]] = {"/chatter": [], "/imu": []}
    for schema, channel, message in messages:
        by_topic[channel.topic].append((schema, message))
    assert [m.data for _, m in by_topic["/chatter"]] == sent_strings
    assert [m.data for _, m in by_topic["/imu"]] == sent_imu
    for items in by_topic.values():
        assert [m.sequence for _, m in items] == list(range(1, count + 1))
        assert all(m.publish_time == m.log_time > 0 for _, m in items)
    log_times = [m.log_time for _, _, m in messages]
    assert log_times == sorted(log_times)

    schema, message = by_topic["/imu"][7]
    decoded, md5 = decode_with_schema(schema, message.data)
    assert md5 == IMU_MD5
    assert decoded.header.seq == 7
    assert decoded.header.frame_id == "imu_link"
    assert decoded.header.stamp.sec == 17
    assert decoded.linear_acceleration.x == 3.5
    schema, message = by_topic["/chatter"][3]
    assert decode_with_schema(schema, message.data)[0].data == "hello 3"
    assert msg.decode(message.data, schema.name).data == "hello 3"


def test_record_unknown_type_keeps_bytes_and_md5(
    router: Graph, client: Graph, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "unknown.mcap"
    pub = router.node("odd").raw_publisher("/odd", "foo_msgs/Bar", UNKNOWN_MD5)
    payloads = [bytes([i, 255 - i, 7]) for i in range(10)]
    with (
        caplog.at_level(logging.WARNING, "hwbridge.recorder"),
        Recorder(client, path, ["/odd"]) as recorder,
    ):
        assert pub.wait_for_subscribers(10)
        for payload in payloads:
            pub.publish_raw(payload)
        assert wait_until(lambda: recorder.stats.messages >= len(payloads))
    pub.close()
    warnings = [r for r in caplog.records if "foo_msgs/Bar" in r.getMessage()]
    assert len(warnings) == 1
    assert "--msg-path" in warnings[0].getMessage()
    assert [c.has_schema for c in recorder.stats.channels] == [False]
    _, summary, messages = read_mcap(path)
    assert summary.schemas == {}
    (channel,) = summary.channels.values()
    assert channel.schema_id == 0
    assert channel.metadata == {"md5sum": UNKNOWN_MD5, "type": "foo_msgs/Bar"}
    assert [m.data for _, _, m in messages] == payloads


def test_record_all_picks_up_topics_that_appear_later(
    router: Graph, client: Graph, tmp_path: Path
) -> None:
    path = tmp_path / "all.mcap"
    early = router.node("early").publisher("/early", "std_msgs/String")
    with Recorder(client, path) as recorder:
        assert early.wait_for_subscribers(10)
        late = router.node("late").publisher("/late/topic", "std_msgs/String")
        assert late.wait_for_subscribers(10)
        early.publish({"data": "early"})
        late.publish({"data": "late"})
        assert wait_until(lambda: recorder.stats.messages >= 2)
    early.close()
    late.close()
    _, summary, messages = read_mcap(path)
    assert {c.topic for c in summary.channels.values()} == {"/early", "/late/topic"}
    assert sorted(msg.decode(m.data, "std_msgs/String").data for _, _, m in messages) == [
        "early",
        "late",
    ]


def test_limit_and_duration_end_the_recording(router: Graph, client: Graph, tmp_path: Path) -> None:
    pub = router.node("limited").publisher("/limited", "std_msgs/String")
    with Recorder(client, tmp_path / "limit.mcap", ["/limited"], limit=5) as recorder:
        assert pub.wait_for_subscribers(10)
        for i in range(20):
            pub.publish({"data": str(i)})
        assert recorder.wait(10)
    assert recorder.stats.messages == 5
    _, _, messages = read_mcap(tmp_path / "limit.mcap")
    assert [msg.decode(m.data, "std_msgs/String").data for _, _, m in messages] == list("01234")

    with Recorder(client, tmp_path / "timed.mcap", ["/limited"], duration=0.2) as recorder:
        assert recorder.wait(10)
        assert recorder.done
    pub.close()


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_compressions(router: Graph, client: Graph, tmp_path: Path, compression: Any) -> None:
    path = tmp_path / f"{compression}.mcap"
    pub = router.node("compress").publisher("/compress", "std_msgs/String")
    with Recorder(client, path, ["/compress"], compression=compression, limit=30) as recorder:
        assert pub.wait_for_subscribers(10)
        for i in range(30):
            pub.publish({"data": "x" * 100 + str(i)})
        assert recorder.wait(10)
    pub.close()
    _, summary, messages = read_mcap(path)
    assert len(messages) == 30
    assert {c.compression for c in summary.chunk_indexes} == {
        "" if compression == "none" else compression
    }


def test_recorder_refuses_to_overwrite(client: Graph, tmp_path: Path) -> None:
    path = tmp_path / "exists.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(RecordingError, match="exists; choose another file name"):
        Recorder(client, path, ["/x"]).start()
    assert path.read_bytes() == b"precious"
    with pytest.raises(RecordingError, match="compression"):
        Recorder(client, path, compression="gzip")  # type: ignore[arg-type]
    for every in (0.0, -1.0):  # (a negative one stopped the writer's queue.get at its start)
        with pytest.raises(RecordingError, match="flush_every must be positive seconds"):
            Recorder(client, path, ["/x"], flush_every=every)
    with Recorder(client, path, ["/x"], overwrite=True):
        pass
    header, summary, messages = read_mcap(path)
    assert (header.profile, summary.statistics.message_count, messages) == ("ros1", 0, [])


# ---------------------------------------------------------------------- playing
Channel = tuple[str, str, str, bool]  # topic, type, md5, write the schema


def write_mcap(
    path: Path,
    messages: list[tuple[str, int, bytes]],
    channels: dict[str, Channel],
    *,
    md5_metadata: bool = True,
    encoding: str = "ros1",
    finish: bool = True,
) -> None:
    """An MCAP file made with the mcap writer alone: (topic, log time ns, bytes) messages;
    without ``finish``, left as a killed recorder leaves it (the chunks written, no summary)."""
    registry = msg.registry()
    with path.open("wb") as stream:
        writer = Writer(stream, chunk_size=512, compression=CompressionType.ZSTD)
        writer.start(profile="ros1", library="test")
        ids: dict[str, int] = {}
        for topic, (_, type_name, md5, with_schema) in channels.items():
            schema_id = 0
            if with_schema:
                schema_id = writer.register_schema(
                    type_name, "ros1msg", registry.definition(type_name).encode()
                )
            metadata = {"md5sum": md5, "type": type_name} if md5_metadata else {}
            ids[topic] = writer.register_channel(topic, encoding, schema_id, metadata)
        for sequence, (topic, log_time, data) in enumerate(messages):
            writer.add_message(ids[topic], log_time, data, log_time, sequence)
        if finish:
            writer.finish()


def sample_file(
    path: Path, *, md5_metadata: bool = True, finish: bool = True
) -> list[tuple[str, int, bytes]]:
    """Strings on /a, Imu on /b, 10 ms apart; returns what the file holds."""
    start = 1_700_000_000_000_000_000
    messages: list[tuple[str, int, bytes]] = []
    for i in range(20):
        if i % 2:
            data = msg.encode(msg.from_dict("sensor_msgs/Imu", imu(i)))
            messages.append(("/b", start + i * 10_000_000, data))
        else:
            data = msg.encode(msg.new("std_msgs/String", data=f"a{i}"))
            messages.append(("/a", start + i * 10_000_000, data))
    channels = {
        "/a": ("/a", "std_msgs/String", STRING_MD5, True),
        "/b": ("/b", "sensor_msgs/Imu", IMU_MD5, True),
    }
    write_mcap(path, messages, channels, md5_metadata=md5_metadata, finish=finish)
    return messages


class Sink:
    """Raw subscribers on a client graph, collecting (topic, type, md5, bytes)."""

    def __init__(self, graph: Graph, topics: list[str]) -> None:
        self.got: list[RawMessage] = []
        self.lock = threading.Lock()
        node = graph.node("sink")
        self.subs = [node.subscriber(t, ANY_TYPE, self.add, raw=True) for t in topics]

    def add(self, message: RawMessage) -> None:
        with self.lock:
            self.got.append(message)

    def of(self, topic: str) -> list[bytes]:
        with self.lock:
            return [m.data for m in self.got if m.topic == topic]

    def __len__(self) -> int:
        with self.lock:
            return len(self.got)


def expected(messages: list[tuple[str, int, bytes]], topic: str) -> list[bytes]:
    return [data for t, _, data in messages if t == topic]


@pytest.mark.parametrize("rate", [0.0, 2.0])
def test_play_publishes_the_recorded_bytes(
    router: Graph, client: Graph, tmp_path: Path, rate: float
) -> None:
    path = tmp_path / "sample.mcap"
    messages = sample_file(path)
    sink = Sink(client, ["/a", "/b"])
    stats = Player(router, path, rate=rate, wait_for_subscribers=10).run()
    assert wait_until(lambda: len(sink) >= len(messages))
    assert sink.of("/a") == expected(messages, "/a")
    assert sink.of("/b") == expected(messages, "/b")
    assert {(m.topic, m.type, m.md5) for m in sink.got} == {
        ("/a", "std_msgs/String", STRING_MD5),
        ("/b", "sensor_msgs/Imu", IMU_MD5),
    }
    assert stats.messages == len(messages)
    assert stats.loops == 1
    assert stats.duration == pytest.approx(0.19)
    assert stats.position == pytest.approx(0.19)


def test_play_filters_topics_and_start(router: Graph, client: Graph, tmp_path: Path) -> None:
    path = tmp_path / "sample.mcap"
    messages = sample_file(path)
    sink = Sink(client, ["/a", "/b"])
    stats = Player(router, path, rate=0, topics=["b"], start=0.045, wait_for_subscribers=10).run()
    want = [data for topic, t, data in messages[5:] if topic == "/b"]
    assert stats.messages == len(want) == 8
    assert wait_until(lambda: len(sink) >= len(want))
    assert sink.of("/b") == want
    assert sink.of("/a") == []
    with pytest.raises(
        RecordingError, match=r"none of the topics /nope is in .* \(it has /a, /b\)"
    ):
        Player(router, path, topics=["/nope"])


def test_play_names_the_topics_it_cannot_play(router: Graph, tmp_path: Path) -> None:
    path = tmp_path / "sample.mcap"
    sample_file(path)
    player = Player(router, path, topics=["/aa", "/b"])
    assert (player.missing, player.recorded) == (("/aa",), ("/a", "/b"))
    with pytest.raises(RecordingError) as info:
        Player(router, path, topics=["/aa", "/bb"])
    assert str(info.value) == (
        f"none of the topics /aa, /bb is in {path}; did you mean /a, /b? (it has /a, /b)"
    )


def test_play_loops_until_stopped(router: Graph, client: Graph, tmp_path: Path) -> None:
    path = tmp_path / "sample.mcap"
    messages = sample_file(path)
    sink = Sink(client, ["/a"])
    player = Player(router, path, rate=0, loop=True, topics=["/a"], wait_for_subscribers=10)
    result: list[Any] = []
    thread = threading.Thread(target=lambda: result.append(player.run()))
    thread.start()
    try:
        assert wait_until(lambda: len(sink) >= 3 * 10)
    finally:
        player.stop()
        thread.join(10)
    assert not thread.is_alive()
    assert result[0].loops >= 2
    assert sink.of("/a")[:20] == expected(messages, "/a") * 2


def test_play_without_md5_metadata_takes_it_from_the_schema(
    router: Graph, client: Graph, tmp_path: Path
) -> None:
    path = tmp_path / "nomd5.mcap"
    messages = sample_file(path, md5_metadata=False)
    sink = Sink(client, ["/a", "/b"])
    Player(router, path, rate=0, wait_for_subscribers=10).run()
    assert wait_until(lambda: len(sink) >= len(messages))
    assert {(m.topic, m.type, m.md5) for m in sink.got} == {
        ("/a", "std_msgs/String", STRING_MD5),
        ("/b", "sensor_msgs/Imu", IMU_MD5),
    }


def test_play_a_truncated_file(
    router: Graph, client: Graph, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "cut.mcap"
    messages = sample_file(path)
    whole = path.read_bytes()
    path.write_bytes(whole[: len(whole) * 3 // 10])  # killed mid-recording: no summary, no footer
    sink = Sink(client, ["/a", "/b"])
    with caplog.at_level(logging.WARNING, "hwbridge.recorder"):
        stats = Player(router, path, rate=0, wait_for_subscribers=10).run()
    assert "no readable summary" in caplog.text
    assert 0 < stats.messages < len(messages)
    assert wait_until(lambda: len(sink) >= stats.messages)
    assert sink.of("/a") == expected(messages, "/a")[: len(sink.of("/a"))]


def test_the_length_of_a_file_without_a_summary_is_known_once_played_through(
    router: Graph, tmp_path: Path
) -> None:
    """A killed recorder's file does not say how long it is: the progress line said
    '3.1 / 0.0 s' all along. Its length is None (not 0) until a pass has read the file to its
    end, then that pass's first to last log time; the line says which it shows."""
    from hwbridge.cli.recordcmd import _play_line

    path = tmp_path / "cut.mcap"
    sample_file(path, finish=False)
    player = Player(router, path, rate=0, wait_for_subscribers=0)
    assert player.stats.duration is None
    assert "0.0 s (no index: length known once played through)" in _play_line(
        player.stats, 0, False
    )
    stats = player.run()
    assert stats.messages > 0 and stats.position > 0
    assert stats.duration == pytest.approx(stats.position)  # (written in log time order)
    assert f"{stats.position:.1f} / {stats.duration:.1f} s, " in _play_line(stats, 0, False)


def test_play_refuses_what_it_cannot_play(router: Graph, tmp_path: Path) -> None:
    cdr = tmp_path / "cdr.mcap"
    write_mcap(
        cdr,
        [("/a", 1, b"\x00")],
        {"/a": ("/a", "std_msgs/String", STRING_MD5, False)},
        encoding="cdr",
    )
    with pytest.raises(RecordingError, match=r"channel /a holds 'cdr' messages; .* ROS 1"):
        Player(router, cdr)
    text = tmp_path / "notes.mcap"
    text.write_text("not a recording")
    with pytest.raises(RecordingError, match="not an MCAP file"):
        Player(router, text)
    text.write_text("\n")  # shorter than the magic: once a struct.error and a traceback
    with pytest.raises(RecordingError, match="not an MCAP file"):
        Player(router, text)
    text.write_bytes(b"")  # a recorder killed before it wrote: once "not an MCAP file ()"
    with pytest.raises(RecordingError, match=r"not an MCAP file \(it is empty\)$"):
        Player(router, text)
    with pytest.raises(RecordingError, match="cannot open"):
        Player(router, tmp_path / "missing.mcap")
    with pytest.raises(RecordingError, match="rate"):
        Player(router, cdr, rate=-1)


def test_record_then_play_round_trip(router: Graph, client: Graph, tmp_path: Path) -> None:
    path = tmp_path / "round.mcap"
    pub = router.node("source").publisher("/round", "sensor_msgs/Imu")
    sent = [msg.encode(msg.from_dict("sensor_msgs/Imu", imu(i))) for i in range(15)]
    with Recorder(client, path, ["/round"], limit=len(sent)) as recorder:
        assert pub.wait_for_subscribers(10)
        for data in sent:
            pub.publish_raw(data)
        assert recorder.wait(10)
    pub.close()
    sink = Sink(client, ["/round"])
    Player(router, path, rate=0, wait_for_subscribers=10).run()
    assert wait_until(lambda: len(sink) >= len(sent))
    assert sink.of("/round") == sent


# ---------------------------------------------------------------------- the command line
def cli(endpoint: str, *args: str) -> list[str]:
    return [sys.executable, "-m", "hwbridge", "--domain", DOMAIN, *args, "--endpoint", endpoint]


def run_cli(endpoint: str, *args: str) -> subprocess.CompletedProcess[str]:
    """Run ``hwbridge ARGS`` on the test graph to its end (at most a minute), output kept."""
    return subprocess.run(
        cli(endpoint, *args), capture_output=True, text=True, timeout=60, check=False
    )


@pytest.fixture
def talker(router: Graph) -> Iterator[Callable[[], int]]:
    """Publishes "n" strings on /talk every 5 ms until the test ends; gives the count sent."""
    pub = router.node("cli_talker").publisher("/talk", "std_msgs/String")
    other = router.node("cli_talker").publisher("/other", "std_msgs/String")
    stop = threading.Event()
    sent = [0]

    def run() -> None:
        while not stop.is_set():
            pub.publish({"data": str(sent[0])})
            other.publish({"data": "other"})
            sent[0] += 1
            stop.wait(0.005)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    yield lambda: sent[0]
    stop.set()
    thread.join()
    pub.close()
    other.close()


def test_cli_record_limit(endpoint: str, talker: Callable[[], int], tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    done = run_cli(endpoint, "record", "-o", str(path), "/talk", "--limit", "20")
    assert done.returncode == 0, done.stderr
    assert "recorded 20 messages" in done.stderr
    _, summary, messages = read_mcap(path)
    assert {c.topic for c in summary.channels.values()} == {"/talk"}
    numbers = [int(msg.decode(m.data, "std_msgs/String").data) for _, _, m in messages]
    assert numbers == list(range(numbers[0], numbers[0] + 20))  # nothing lost, in order


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_cli_record_interrupted_leaves_a_valid_file(
    endpoint: str, router: Graph, talker: Callable[[], int], tmp_path: Path, signum: int
) -> None:
    path = tmp_path / "interrupted.mcap"

    def recorder_sessions() -> set[str]:
        return {e.session for e in router.snapshot(0.5).of_kind("sub") if e.name == "/other"}

    earlier = recorder_sessions()
    process = subprocess.Popen(
        cli(endpoint, "record", "-o", str(path), "/talk", "/other"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        started = wait_until(
            lambda: process.poll() is not None or bool(recorder_sessions() - earlier),
            timeout=20,
            step=0.1,
        )
        assert started and process.poll() is None, process.communicate()[1]
        sent_before = talker()
        assert wait_until(lambda: talker() >= sent_before + 20)  # some traffic to record
        process.send_signal(signum)
        _, err = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 0, err
    assert "recorded" in err
    _, summary, messages = read_mcap(path)
    assert summary is not None and summary.statistics.message_count == len(messages) > 0
    assert {c.topic for c in summary.channels.values()} == {"/talk", "/other"}
    for schema, _, message in messages:
        decode_with_schema(schema, message.data)


def _messages_in(path: Path) -> int:
    """Message records readable in ``path``, up to where it ends (mid-record, say)."""
    from mcap.records import Message as McapMessage
    from mcap.stream_reader import StreamReader

    count = 0
    with contextlib.suppress(Exception), path.open("rb") as stream:
        for record in StreamReader(stream).records:
            count += isinstance(record, McapMessage)
    return count


def test_cli_record_killed_leaves_what_it_had_recorded(
    endpoint: str, talker: Callable[[], int], tmp_path: Path
) -> None:
    """A recorder killed without finishing its file (SIGKILL: no footer, no summary) has
    flushed its messages up to about a second before: they are in the file. It used to write
    only whole 1 MiB chunks, and a minute of a few topics left an empty file."""
    path = tmp_path / "killed.mcap"
    process = subprocess.Popen(
        cli(endpoint, "record", "-o", str(path), "/talk"),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert wait_until(lambda: process.poll() is not None or _messages_in(path) >= 20, 30)
        assert process.poll() is None, process.communicate()[1]
        process.kill()
        process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert _messages_in(path) >= 20


def test_cli_record_warns_of_a_topic_nothing_publishes(
    endpoint: str, router: Graph, tmp_path: Path
) -> None:
    """A misspelt topic gets one warning naming the published one spelt alike; recording goes
    on, and takes the misspelt topic too once something publishes it."""
    path = tmp_path / "misspelt.mcap"
    node = router.node("odom_talker")
    odom = node.publisher("/t/odom", "std_msgs/String")
    late: list[Any] = []
    stop = threading.Event()

    def run() -> None:
        while not stop.is_set():
            odom.publish({"data": "odom"})
            for pub in late[:1]:
                pub.publish({"data": "late"})
            stop.wait(0.005)

    talking = threading.Thread(target=run, daemon=True)
    talking.start()
    process = subprocess.Popen(
        cli(endpoint, "record", "-o", str(path), "/t/odm", "/t/odom"),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: list[str] = []
    assert process.stderr is not None
    reading = threading.Thread(target=lambda: lines.extend(process.stderr or ()), daemon=True)
    reading.start()

    def warned() -> list[str]:
        return [line for line in list(lines) if line.startswith("warning:")]

    try:
        assert wait_until(lambda: bool(warned()) or process.poll() is not None, timeout=30)
        assert process.poll() is None, "".join(lines)  # the warning did not end the recording
        late.append(node.publisher("/t/odm", "std_msgs/String"))
        # the plain progress lines (stderr is no terminal) count the late topic's messages
        assert wait_until(
            lambda: any(re.search(r"/t/odm [1-9]", line) for line in list(lines)), timeout=30
        ), "".join(lines)
        process.send_signal(signal.SIGINT)
        process.wait(timeout=30)
        reading.join(timeout=30)
    finally:
        stop.set()
        talking.join()
        for pub in (odom, *late):
            pub.close()
        if process.poll() is None:
            process.kill()
            process.wait()
    err = "".join(lines)
    assert process.returncode == 0, err
    assert len(warned()) == 1, err  # /t/odom is published: no warning of it
    assert "no publisher of /t/odm" in warned()[0]
    assert "did you mean /t/odom?" in warned()[0]
    _, summary, messages = read_mcap(path)
    counts = {c.topic: 0 for c in summary.channels.values()}
    for _, channel, _ in messages:
        counts[channel.topic] += 1
    assert counts["/t/odom"] > 0 and counts["/t/odm"] > 0


def test_cli_record_summary_shows_a_silent_topic(
    endpoint: str, talker: Callable[[], int], tmp_path: Path
) -> None:
    """A recording that ends before the discovery grace still warns, and its summary lists
    the named topic that got nothing."""
    path = tmp_path / "silent.mcap"
    done = run_cli(endpoint, "record", "-o", str(path), "/talk", "/tlak", "--limit", "20")
    assert done.returncode == 0, done.stderr
    assert "warning: no publisher of /tlak yet; did you mean /talk?" in done.stderr
    assert "recorded 20 messages" in done.stderr and " on 1 topic " in done.stderr
    assert re.search(r"^  /tlak +\? +0 messages", done.stderr, re.MULTILINE), done.stderr


def test_cli_play(endpoint: str, client: Graph, tmp_path: Path) -> None:
    path = tmp_path / "sample.mcap"
    messages = sample_file(path)
    sink = Sink(client, ["/a", "/b"])
    done = run_cli(endpoint, "play", str(path), "--rate", "0", "--topics", "/b", "--wait", "10")
    assert done.returncode == 0, done.stderr
    assert "played 10 messages" in done.stderr
    assert wait_until(lambda: len(sink) >= 10)
    assert sink.of("/b") == expected(messages, "/b")
    assert sink.of("/a") == []


def test_cli_play_warns_of_a_topic_not_in_the_file(
    endpoint: str, client: Graph, tmp_path: Path
) -> None:
    """Before, '--topics /bb' was dropped without a word (a log line at most); now each topic
    not in the file gets a warning naming the recorded ones spelt alike, and if none of them is
    there that is the error (status 1)."""
    path = tmp_path / "sample.mcap"
    messages = sample_file(path)
    sink = Sink(client, ["/a", "/b"])
    argv = ("play", str(path), "--rate", "0", "--wait", "10", "-q")
    done = run_cli(endpoint, *argv, "--topics", "/a,/bb")
    assert done.returncode == 0, done.stderr
    assert done.stderr.splitlines() == [
        f"warning: /bb is not in {path}; did you mean /b? (playing the others)"
    ]
    assert wait_until(lambda: len(sink) >= 10)
    assert sink.of("/a") == expected(messages, "/a")
    for asked in (["--topics", "/aa,/bb"], ["/aa", "/bb"]):
        done = run_cli(endpoint, *argv, *asked)
        assert done.returncode == 1, done.stderr
        assert done.stderr.splitlines() == [
            f"error: none of the topics /aa, /bb is in {path}; did you mean /a, /b? (it has /a, /b)"
        ]
    done = run_cli(endpoint, *argv, "/a/")
    assert done.returncode == 1, done.stderr
    assert done.stderr.splitlines() == [
        "error: '/a/': a topic name does not end with '/'; did you mean /a?"
    ]


def test_cli_play_summary_lists_every_topic_asked_for(
    endpoint: str, router: Graph, tmp_path: Path
) -> None:
    """As record's does: before, '--topics /a,/bb' gave a summary of /a alone."""
    path = tmp_path / "sample.mcap"
    sample_file(path)
    done = run_cli(endpoint, "play", str(path), "--rate", "0", "--wait", "0", "--topics", "/a,/bb")
    assert done.returncode == 0, done.stderr
    assert "played 10 messages (65 B) on 1 topic in " in done.stderr, done.stderr
    assert re.search(r"^  /a +std_msgs/String +10 messages, 65 B$", done.stderr, re.M)
    assert re.search(r"^  /bb +\? +0 messages, 0 B$", done.stderr, re.M), done.stderr


def test_cli_play_of_a_file_without_a_summary_warns_after_playing(
    endpoint: str, router: Graph, tmp_path: Path
) -> None:
    """A file a killed recorder left has no summary to tell its topics before playing: before,
    '--topics /bb' played nothing and said nothing (status 0). Now each topic asked for that
    never appeared is warned of once the file is played, naming those that did; if none did,
    that is the error a complete file gives at once (status 1)."""
    path = tmp_path / "cut.mcap"
    sample_file(path, finish=False)
    argv = ("play", str(path), "--rate", "0", "--wait", "0")
    done = run_cli(endpoint, *argv, "--topics", "/a,/bb")
    assert done.returncode == 0, done.stderr
    lines = done.stderr.splitlines()
    assert lines[-1] == f"warning: /bb was not in {path}; did you mean /b? (played the others)"
    assert re.search(r"^  /bb +\? +0 messages, 0 B$", done.stderr, re.M), done.stderr
    done = run_cli(endpoint, *argv, "--topics", "/bb")
    assert done.returncode == 1, done.stderr
    assert done.stderr.splitlines()[-1] == (
        f"error: none of the topics /bb is in {path}; did you mean /b? (it has /a, /b)"
    )


def test_cli_play_loop_of_a_file_without_a_summary_warns_after_its_first_pass(
    endpoint: str, router: Graph, tmp_path: Path
) -> None:
    """'play --loop' of a file a killed recorder left: before, a topic asked for that never
    appeared was warned of only once Ctrl-C ended the loop, and 'ends early' was said again on
    every pass. Now both are said once, when the first pass has read the file to its end; the
    loop plays on, and Ctrl-C ends it cleanly."""
    path = tmp_path / "cut.mcap"
    sample_file(path, finish=False)
    process = subprocess.Popen(
        cli(endpoint, "play", str(path), "--loop", "--wait", "0", "--topics", "/a,/bb"),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: list[str] = []
    reading = threading.Thread(target=lambda: lines.extend(process.stderr or ()), daemon=True)
    reading.start()
    warning = f"warning: /bb is not in {path}; did you mean /b? (playing the others)\n"

    def passes() -> int:
        """The highest pass a progress line has shown (one every 2 s: stderr is no terminal)."""
        shown = [re.search(r", pass (\d+)$", line) for line in list(lines)]
        return max((int(found.group(1)) for found in shown if found), default=0)

    try:
        assert wait_until(lambda: warning in lines or process.poll() is not None, timeout=30)
        assert process.poll() is None, "".join(lines)  # warned while the loop plays on
        assert wait_until(lambda: passes() >= 3 or process.poll() is not None, timeout=30)
        assert process.poll() is None, "".join(lines)
        process.send_signal(signal.SIGINT)
        process.wait(timeout=30)
        reading.join(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    err = "".join(lines)
    assert process.returncode == 0, err
    assert lines.count(warning) == 1, err  # not again on later passes, nor at the end
    assert sum("ends early" in line for line in lines) == 1, err
    assert re.search(r"^  /bb +\? +0 messages, 0 B$", err, re.M), err
    # none of the topics asked for in it: the error, after one pass, and no warning before it
    done = run_cli(endpoint, "play", str(path), "--loop", "--wait", "0", "--topics", "/bb")
    assert done.returncode == 1, done.stderr
    assert "warning: /bb" not in done.stderr
    assert done.stderr.splitlines()[-1] == (
        f"error: none of the topics /bb is in {path}; did you mean /b? (it has /a, /b)"
    )


def test_cli_play_warns_in_the_commands_own_words(
    endpoint: str, router: Graph, tmp_path: Path
) -> None:
    """The player's warnings (a file with no summary, that ends early) read as the command's
    own: 'warning: ...'. They were log lines ('WARNING hwbridge.recorder: ...') beside its
    'warning: /bb was not in ...'. The info lines -v adds are still a log's."""
    path = tmp_path / "cut.mcap"
    sample_file(path, finish=False)
    argv = ("-v", "play", str(path), "--rate", "0", "--wait", "0", "-q", "--topics", "/a,/bb")
    done = run_cli(endpoint, *argv)
    assert done.returncode == 0, done.stderr
    lines = done.stderr.splitlines()
    warnings = [line for line in lines if line.startswith("warning: ")]
    assert len(warnings) == 3, done.stderr
    assert warnings[0].startswith(f"warning: {path} has no readable summary ("), done.stderr
    assert warnings[1].startswith(f"warning: {path} ends early ("), done.stderr
    assert warnings[2] == f"warning: /bb was not in {path}; did you mean /b? (played the others)"
    assert not [line for line in lines if line.startswith(("WARNING", "ERROR"))], done.stderr
    assert f"INFO hwbridge.recorder: topic /bb is not in {path}" in lines, done.stderr


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_cli_record_says_a_write_error_once(
    endpoint: str, talker: Callable[[], int], tmp_path: Path
) -> None:
    """A recording that cannot be written (/dev/full: no space left) ends with status 1 and the
    error once. The recorder's writer logged it as well, when it happened: the same line twice
    once the library's errors read as the command's own (before, 'ERROR hwbridge.recorder:')."""
    done = run_cli(endpoint, "record", "-f", "-o", "/dev/full", "/talk", "-q")
    assert done.returncode == 1, done.stderr
    assert done.stderr.splitlines() == [
        "error: recording to /dev/full failed: [Errno 28] No space left on device"
    ]


def test_cli_errors(endpoint: str, router: Graph, tmp_path: Path) -> None:
    cdr = tmp_path / "cdr.mcap"
    write_mcap(
        cdr,
        [("/a", 1, b"\x00")],
        {"/a": ("/a", "std_msgs/String", STRING_MD5, False)},
        encoding="cdr",
    )
    done = run_cli(endpoint, "play", str(cdr))
    assert done.returncode == 1
    assert "'cdr' messages" in done.stderr
    done = subprocess.run(
        cli(endpoint, "record", "/a", "--all", "-o", str(tmp_path / "y.mcap")),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        env={**os.environ, "COLUMNS": "200"},
    )
    assert done.returncode == 2
    assert "give topics or --all, not both" in done.stderr
