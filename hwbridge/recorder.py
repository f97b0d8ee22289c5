"""Record graph topics to MCAP files and play them back, bytes unchanged.

Files follow MCAP's ``ros1`` profile, so Foxglove, the ``mcap`` CLI and ``rosbags`` read them:
one schema per message type (encoding ``ros1msg``, name the ROS 1 type name, data the full
definition text with its dependencies, as rosbag stores it), one channel per topic and type
(message encoding ``ros1``, metadata ``md5sum`` and ``type`` as in a rosbag connection header),
and the ROS 1 serialized bytes exactly as they travelled on the graph::

    from hwbridge.graph import Graph
    from hwbridge.recorder import Player, Recorder

    with Graph.attached() as graph:
        with Recorder(graph, "run.mcap", ["/odom", "/imu"], limit=1000) as recorder:
            recorder.wait()                       # until 1000 messages (or stop() elsewhere)
        print(recorder.stats.messages)
        Player(graph, "run.mcap", rate=2.0).run()

A message's log and publish times are both the time it was received (the graph carries no send
time). A message whose type is not in the registry (or whose md5 differs from the registry's) is
still recorded, on a channel without a schema that keeps the type and md5 in its metadata.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import struct
import threading
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Final, Literal

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel, Message, Schema
from mcap.summary import Summary
from mcap.writer import CompressionType, Writer

from hwbridge._version import __version__
from hwbridge.errors import HwBridgeError, UnknownTypeError
from hwbridge.graph.core import ANY_TYPE, RawMessage
from hwbridge.graph.names import resolve_name

if TYPE_CHECKING:
    from hwbridge.graph import Graph, GraphEntity, Node, Publisher, Subscriber
    from hwbridge.msg import TypeRegistry

__all__ = [
    "COMPRESSIONS",
    "ChannelStats",
    "Compression",
    "Player",
    "PlayerStats",
    "Recorder",
    "RecorderStats",
    "RecordingError",
]

log = logging.getLogger("hwbridge.recorder")

Compression = Literal["zstd", "lz4", "none"]
COMPRESSIONS: Final[dict[str, CompressionType]] = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}
"""Chunk compressions the ``mcap`` writer offers (it depends on zstandard and lz4)."""

SCHEMA_ENCODING: Final = "ros1msg"
MESSAGE_ENCODING: Final = "ros1"
PROFILE: Final = "ros1"
_SEQUENCE_MODULUS: Final = 2**32  # MCAP sequence numbers are uint32


class RecordingError(HwBridgeError):
    """An MCAP file cannot be written, read or played."""


# ---------------------------------------------------------------------- statistics
@dataclass(frozen=True)
class ChannelStats:
    """Messages and payload bytes of one topic and type, recorded or played."""

    topic: str
    type: str
    md5: str
    messages: int = 0
    bytes: int = 0
    has_schema: bool = True
    """False when the type was not in the registry: bytes recorded, definition unknown."""


class _ChannelTotals:
    """Totals over ``channels`` (of a recording or a playback)."""

    channels: tuple[ChannelStats, ...]

    @property
    def messages(self) -> int:
        return sum(c.messages for c in self.channels)

    @property
    def bytes(self) -> int:
        return sum(c.bytes for c in self.channels)


@dataclass(frozen=True)
class RecorderStats(_ChannelTotals):
    """A snapshot of a recording in progress (or finished)."""

    path: Path
    elapsed: float
    """Seconds since :meth:`Recorder.start` (until :meth:`Recorder.stop` once stopped)."""
    channels: tuple[ChannelStats, ...] = ()
    dropped: int = 0
    """Messages lost because the write buffer was full (the disk could not keep up)."""


@dataclass(frozen=True)
class PlayerStats(_ChannelTotals):
    """A snapshot of a playback in progress (or finished)."""

    path: Path
    elapsed: float
    """Wall-clock seconds since :meth:`Player.run` began."""
    position: float = 0.0
    """Seconds into the recording of the last message published."""
    duration: float = 0.0
    """Length of the recording in seconds (first to last message)."""
    loops: int = 0
    """Passes over the file completed."""
    channels: tuple[ChannelStats, ...] = ()


@dataclass
class _Counter:
    topic: str
    type: str
    md5: str
    has_schema: bool = True
    messages: int = 0
    bytes: int = 0

    def freeze(self) -> ChannelStats:
        return ChannelStats(
            self.topic, self.type, self.md5, self.messages, self.bytes, self.has_schema
        )


# ---------------------------------------------------------------------- recorder
_STOP: Final = object()


@dataclass
class _Subscribe:
    """Request to the writer thread: subscribe to a topic discovery found."""

    topic: str


class _Pending:
    """Placeholder for a discovered topic the writer thread has not subscribed to yet."""

    def close(self) -> None:
        """Nothing to undeclare yet."""


_PENDING: Final = _Pending()


class Recorder:
    """Records topics of a graph into an MCAP file.

    ``topics`` names the topics to record; ``None`` (or empty) records every topic that has a
    publisher, including those that appear while recording. Recording ends by :meth:`stop`; after
    ``limit`` messages or ``duration`` seconds it stops taking messages and :meth:`wait` returns.
    Messages go from Zenoh's threads through a queue of at most ``buffer_bytes`` to one writer
    thread; what does not fit is dropped and counted in ``stats.dropped``.
    """

    def __init__(
        self,
        graph: Graph,
        path: str | Path,
        topics: Iterable[str] | None = None,
        *,
        compression: Compression = "zstd",
        duration: float | None = None,
        limit: int | None = None,
        overwrite: bool = False,
        chunk_size: int = 1 << 20,
        buffer_bytes: int = 256 << 20,
        node_name: str | None = None,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise RecordingError(
                f"unknown compression {compression!r}; use one of {', '.join(COMPRESSIONS)}"
            )
        if duration is not None and duration <= 0:
            raise RecordingError(f"duration must be positive, got {duration:g} s")
        if limit is not None and limit < 1:
            raise RecordingError(f"limit must be at least 1 message, got {limit}")
        self.graph = graph
        self.path = Path(path)
        self.topics: tuple[str, ...] = tuple(dict.fromkeys(resolve_name(t) for t in topics or ()))
        self.compression: Compression = compression
        self.duration = duration
        self.limit = limit
        self.overwrite = overwrite
        self.chunk_size = chunk_size
        self.buffer_bytes = buffer_bytes
        self.node_name = node_name or f"hwbridge_record_{graph.zid[:8]}"
        self.registry: TypeRegistry = graph.registry

        self._lock = threading.Lock()
        self._queue: queue.SimpleQueue[object] = queue.SimpleQueue()
        self._done = threading.Event()
        self._state: Literal["new", "recording", "stopping", "stopped"] = "new"
        self._accepted = 0
        self._queued_bytes = 0
        self._dropped = 0
        self._deadline: float | None = None
        self._started = 0.0
        self._stopped: float | None = None
        self._error: BaseException | None = None
        self._node: Node | None = None
        self._subscribers: dict[str, Subscriber | _Pending] = {}
        self._watch: object | None = None
        self._stream: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._thread: threading.Thread | None = None
        # owned by the writer thread
        self._schemas: dict[tuple[str, str], int] = {}
        self._channels: dict[tuple[str, str, str], int] = {}
        self._sequences: dict[int, int] = {}
        self._counters: dict[tuple[str, str, str], _Counter] = {}
        self._warned: set[tuple[str, str]] = set()

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> Recorder:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        """Create the file and begin recording (returns at once)."""
        if self._state != "new":
            raise RecordingError("a Recorder records once; make a new one")
        try:
            stream = self.path.open("wb" if self.overwrite else "xb")
        except FileExistsError:
            raise RecordingError(
                f"{self.path} exists; choose another file name or allow overwriting "
                "(--force on the command line)"
            ) from None
        except OSError as exc:
            raise RecordingError(f"cannot create {self.path}: {exc}") from exc
        try:
            writer = Writer(
                stream, chunk_size=self.chunk_size, compression=COMPRESSIONS[self.compression]
            )
            writer.start(profile=PROFILE, library=f"hwbridge {__version__}")
        except McapError as exc:  # compression library missing
            stream.close()
            self.path.unlink(missing_ok=True)
            raise RecordingError(f"cannot write {self.compression} MCAP: {exc}") from exc
        self._stream, self._writer = stream, writer
        self._started = time.monotonic()
        if self.duration is not None:
            self._deadline = self._started + self.duration
        self._state = "recording"
        self._thread = threading.Thread(
            target=self._write_loop, name=f"hwbridge-record {self.path.name}", daemon=True
        )
        self._thread.start()
        try:
            self._node = self.graph.node(self.node_name)
            if self.topics:
                for topic in self.topics:
                    self._subscribe(topic)
            else:
                self._watch = self.graph.watch(self._on_entity)
        except BaseException:
            with contextlib.suppress(HwBridgeError):
                self.stop()
            raise
        log.info("recording %s to %s", ", ".join(self.topics) or "all topics", self.path)

    def wait(self, timeout: float | None = None) -> bool:
        """Block until the limit or duration is reached (or writing failed); False on timeout."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._done.is_set():
            now = time.monotonic()
            if self._deadline is not None and now >= self._deadline:
                self._done.set()
                break
            if deadline is not None and now >= deadline:
                return False
            waits = [0.5]
            if deadline is not None:
                waits.append(deadline - now)
            if self._deadline is not None:
                waits.append(self._deadline - now)
            self._done.wait(max(0.0, min(waits)))
        return True

    @property
    def done(self) -> bool:
        """Whether the limit or duration was reached, or writing failed."""
        if self._deadline is not None and time.monotonic() >= self._deadline:
            self._done.set()
        return self._done.is_set()

    def stop(self) -> RecorderStats:
        """Stop taking messages, write what is queued, finish the file (footer, indexes).

        Idempotent; raises RecordingError if writing failed at any point.
        """
        with self._lock:
            state = self._state
            if state == "new":
                self._state = "stopped"
            elif state == "recording":
                self._state = "stopping"
                self._stopped = time.monotonic()
                self._queue.put(_STOP)
        if state == "recording":
            if self._watch is not None:
                self.graph._forget(self._watch)
            if self._thread is not None:
                self._thread.join()  # the only other thread that subscribes
            with self._lock:
                subscribers = list(self._subscribers.values())
            for subscriber in subscribers:
                subscriber.close()
            self._done.set()
            with self._lock:
                self._state = "stopped"
            log.info("recorded %d messages to %s", self.stats.messages, self.path)
        if self._error is not None:
            raise RecordingError(f"recording to {self.path} failed: {self._error}")
        return self.stats

    @property
    def failed(self) -> BaseException | None:
        """The error that stopped the writer thread, if any."""
        return self._error

    @property
    def stats(self) -> RecorderStats:
        """What was recorded so far (a consistent snapshot)."""
        with self._lock:
            channels = tuple(c.freeze() for c in self._counters.values())
            dropped = self._dropped
        end = self._stopped if self._stopped is not None else time.monotonic()
        elapsed = end - self._started if self._started else 0.0
        return RecorderStats(self.path, elapsed, channels, dropped)

    # ------------------------------------------------------------------ Zenoh threads
    def _on_entity(self, entity: GraphEntity, alive: bool) -> None:
        name = entity.name
        if not alive or entity.kind != "pub" or not name:
            return
        with self._lock:
            if self._state != "recording" or name in self._subscribers:
                return
            self._subscribers[name] = _PENDING  # reserved until the writer thread subscribes
            self._queue.put(_Subscribe(name))

    def _on_message(self, message: RawMessage) -> None:
        received = time.time_ns()
        size = len(message.data)
        with self._lock:
            if self._state != "recording" or self._done.is_set():
                return
            if self._deadline is not None and time.monotonic() >= self._deadline:
                self._done.set()
                return
            if self._queued_bytes + size > self.buffer_bytes:
                self._dropped += 1
                if self._dropped == 1:
                    log.warning(
                        "write buffer full (%d bytes): dropping messages; the disk is too slow "
                        "for this rate (drops are counted)",
                        self.buffer_bytes,
                    )
                return
            self._queued_bytes += size
            self._accepted += 1
            if self.limit is not None and self._accepted >= self.limit:
                self._done.set()
            self._queue.put((received, message))

    # ------------------------------------------------------------------ writer thread
    def _subscribe(self, topic: str) -> None:
        assert self._node is not None
        subscriber = self._node.subscriber(topic, ANY_TYPE, self._on_message, raw=True)
        with self._lock:
            self._subscribers[topic] = subscriber
        log.debug("subscribed to %s", subscriber.topic)

    def _write_loop(self) -> None:
        writer, stream = self._writer, self._stream
        assert writer is not None and stream is not None
        try:
            while True:
                item = self._queue.get()
                if item is _STOP:
                    break
                if self._error is not None:
                    continue  # keep draining; the file is already failed
                try:
                    if isinstance(item, _Subscribe):
                        self._subscribe_discovered(item.topic)
                    else:
                        assert isinstance(item, tuple)
                        received, message = item
                        self._write(writer, received, message)
                except Exception as exc:  # noqa: BLE001 - disk full, I/O errors: reported by stop()
                    log.error("recording to %s failed: %s", self.path, exc)
                    self._error = exc
                    self._done.set()
            try:
                writer.finish()  # type: ignore[no-untyped-call]
            except Exception as exc:  # noqa: BLE001 - reported by stop()
                self._error = self._error or exc
        finally:
            try:
                stream.close()
            except OSError as exc:
                self._error = self._error or exc

    def _subscribe_discovered(self, topic: str) -> None:
        with self._lock:
            if self._state != "recording":
                return
        try:
            self._subscribe(topic)
        except HwBridgeError as exc:  # a name hwbridge cannot subscribe to: skip it, say so
            log.warning("cannot record %s: %s", topic, exc)

    def _write(self, writer: Writer, received: int, message: RawMessage) -> None:
        key = (message.topic, message.type, message.md5)
        channel_id = self._channels.get(key)
        if channel_id is None:
            channel_id = self._register(writer, message)
        sequence = self._sequences[channel_id] = (self._sequences[channel_id] + 1) % (
            _SEQUENCE_MODULUS
        )
        writer.add_message(
            channel_id,
            log_time=received,
            data=message.data,
            publish_time=received,
            sequence=sequence,
        )
        size = len(message.data)
        with self._lock:
            self._queued_bytes -= size
            counter = self._counters[key]
            counter.messages += 1
            counter.bytes += size

    def _register(self, writer: Writer, message: RawMessage) -> int:
        schema_key = (message.type, message.md5)
        schema_id = self._schemas.get(schema_key)
        if schema_id is None:
            definition = self._definition(message)
            schema_id = (
                0
                if definition is None
                else writer.register_schema(
                    name=message.type, encoding=SCHEMA_ENCODING, data=definition.encode()
                )
            )
            self._schemas[schema_key] = schema_id
        channel_id: int = writer.register_channel(
            topic=message.topic,
            message_encoding=MESSAGE_ENCODING,
            schema_id=schema_id,
            metadata={"md5sum": message.md5, "type": message.type},
        )
        self._channels[(message.topic, message.type, message.md5)] = channel_id
        self._sequences[channel_id] = 0
        with self._lock:
            self._counters[(message.topic, message.type, message.md5)] = _Counter(
                message.topic, message.type, message.md5, has_schema=schema_id != 0
            )
        return channel_id

    def _definition(self, message: RawMessage) -> str | None:
        """The registry's definition of the message's type if its md5 matches, else None."""
        problem = ""
        if not message.type or not message.md5:
            problem = "carries no type or md5 (its publisher sent no hwbridge attachment)"
        else:
            try:
                known = self.registry.message(message.type)
            except UnknownTypeError:
                problem = f"has type {message.type}, which is not in the message registry"
            else:
                if known.md5 == message.md5:
                    return self.registry.definition(message.type)
                problem = (
                    f"has type {message.type} with md5 {message.md5}, but the registry's "
                    f"{message.type} has md5 {known.md5} (another version of the definition)"
                )
        if (message.type, message.md5) not in self._warned:
            self._warned.add((message.type, message.md5))
            log.warning(
                "topic %s %s; recording its bytes without a schema (type and md5 are kept in the "
                "channel metadata); add the package with --msg-path or HWBRIDGE_MSG_PATH to "
                "record its definition",
                message.topic,
                problem,
            )
        return None


# ---------------------------------------------------------------------- player
@dataclass(frozen=True)
class _Route:
    """Where one recorded channel is published."""

    topic: str
    type: str
    md5: str


@dataclass
class _FileInfo:
    summary: Summary | None
    start_ns: int | None = None
    end_ns: int | None = None
    routes: dict[int, _Route] = field(default_factory=dict)


class Player:
    """Publishes the messages of an MCAP file (ROS 1 encoded) on a graph, keeping their timing.

    ``rate`` scales time (2.0 plays twice as fast; 0 plays as fast as possible), ``start`` skips
    that many seconds from the beginning, ``topics`` keeps only those topics and ``loop`` starts
    over at the end until :meth:`stop`. Before the first message, the player waits up to
    ``wait_for_subscribers`` seconds for every topic to have a subscriber. The file is checked
    when the Player is made: RecordingError if it is not MCAP or not ROS 1 encoded.
    """

    def __init__(
        self,
        graph: Graph,
        path: str | Path,
        *,
        rate: float = 1.0,
        loop: bool = False,
        topics: Iterable[str] | None = None,
        start: float = 0.0,
        wait_for_subscribers: float = 1.0,
        node_name: str | None = None,
    ) -> None:
        if rate < 0:
            raise RecordingError(f"rate must be 0 (as fast as possible) or positive, got {rate:g}")
        if start < 0:
            raise RecordingError(f"start must be 0 or positive, got {start:g} s")
        self.graph = graph
        self.path = Path(path)
        self.rate = rate
        self.loop = loop
        self.topics: tuple[str, ...] | None = (
            tuple(dict.fromkeys(resolve_name(t) for t in topics)) if topics else None
        )
        self.start = start
        self.wait_for_subscribers = wait_for_subscribers
        self.node_name = node_name or f"hwbridge_play_{graph.zid[:8]}"
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._counters: dict[int, _Counter] = {}
        self._position = 0.0
        self._loops = 0
        self._began: float | None = None
        self._ended: float | None = None
        self._info = self._inspect()

    # ------------------------------------------------------------------ file
    def _open(self) -> IO[bytes]:
        try:
            return self.path.open("rb")
        except OSError as exc:
            raise RecordingError(f"cannot open {self.path}: {exc.strerror or exc}") from exc

    def _inspect(self) -> _FileInfo:
        with self._open() as stream:
            try:
                reader = make_reader(stream)
            except McapError as exc:
                raise RecordingError(f"{self.path} is not an MCAP file ({exc})") from exc
            try:
                summary = reader.get_summary()
            except (McapError, struct.error, ValueError, OSError) as exc:
                log.warning(
                    "%s has no readable summary (%s): it was probably not closed cleanly; "
                    "playing the messages it holds in file order",
                    self.path,
                    _describe(exc),
                )
                return _FileInfo(summary=None)
        info = _FileInfo(summary=summary)
        if summary is None:
            return info  # valid but unindexed: checked while playing
        if summary.statistics is not None and summary.statistics.message_count:
            info.start_ns = summary.statistics.message_start_time
            info.end_ns = summary.statistics.message_end_time
        elif summary.chunk_indexes:
            info.start_ns = min(c.message_start_time for c in summary.chunk_indexes)
            info.end_ns = max(c.message_end_time for c in summary.chunk_indexes)
        wanted = set(self.topics) if self.topics is not None else None
        present = {channel.topic for channel in summary.channels.values()}
        if wanted is not None:
            missing = sorted(wanted - present)
            if missing == sorted(wanted):
                raise RecordingError(
                    f"none of the topics {', '.join(missing)} is in {self.path}; "
                    f"it has {', '.join(sorted(present)) or 'no topics'}"
                )
            for topic in missing:
                log.warning("topic %s is not in %s", topic, self.path)
        for channel in summary.channels.values():
            if wanted is None or channel.topic in wanted:
                schema = summary.schemas.get(channel.schema_id)
                info.routes[channel.id] = self._route(channel, schema)
        return info

    def _route(self, channel: Channel, schema: Schema | None) -> _Route:
        if channel.message_encoding != MESSAGE_ENCODING:
            raise RecordingError(
                f"{self.path}: channel {channel.topic} holds {channel.message_encoding!r} "
                f"messages; hwbridge plays ROS 1 ('{MESSAGE_ENCODING}') recordings only, such "
                "as those of 'hwbridge record' or ROS 1 bags converted with 'mcap convert'"
            )
        if schema is not None and schema.encoding != SCHEMA_ENCODING:
            raise RecordingError(
                f"{self.path}: channel {channel.topic} has a {schema.encoding!r} schema; "
                f"ROS 1 messages need a '{SCHEMA_ENCODING}' schema"
            )
        type_name = channel.metadata.get("type") or (schema.name if schema is not None else "")
        md5 = channel.metadata.get("md5sum", "")
        if not md5 and schema is not None and schema.data:
            md5 = _definition_md5(schema)
        if not md5 and type_name:
            with contextlib.suppress(HwBridgeError):
                md5 = self.graph.registry.message(type_name).md5
        if not type_name or not md5:
            raise RecordingError(
                f"{self.path}: channel {channel.topic} names no message type and md5 "
                "(no 'type'/'md5sum' metadata and no usable schema); cannot publish it"
            )
        return _Route(channel.topic, type_name, md5)

    def _messages(self) -> Iterator[tuple[Schema | None, Channel, Message]]:
        """One pass over the selected messages, in log time order (file order if unindexed)."""
        with self._open() as stream:
            if self._info.summary is not None:
                # Bounds filtered here: the reader's keyword for them changed across mcap versions.
                source = make_reader(stream).iter_messages(topics=self.topics, log_time_order=True)
                start = self._start_ns()
                if start is None:
                    yield from self._skip(source)
                else:
                    yield from (item for item in source if item[2].log_time >= start)
                return
            try:
                yield from self._skip(
                    NonSeekingReader(stream).iter_messages(topics=self.topics, log_time_order=False)
                )
            except (McapError, struct.error, ValueError, OSError) as exc:
                log.warning("%s ends early (%s); played what it holds", self.path, _describe(exc))

    def _skip(
        self, source: Iterable[tuple[Schema | None, Channel, Message]]
    ) -> Iterator[tuple[Schema | None, Channel, Message]]:
        """Drop the first ``start`` seconds when the file does not say where it starts."""
        offset = round(self.start * 1e9)
        first: int | None = None
        for item in source:
            first = item[2].log_time if first is None else first
            if item[2].log_time >= first + offset:
                yield item

    def _start_ns(self) -> int | None:
        if self._info.start_ns is None:
            return None
        return self._info.start_ns + round(self.start * 1e9)

    # ------------------------------------------------------------------ playing
    def run(self) -> PlayerStats:
        """Play the file (once, or until :meth:`stop` with ``loop``); returns the final stats."""
        node = self.graph.node(self.node_name)
        publishers: dict[int, Publisher] = {}
        try:
            for channel_id, route in self._info.routes.items():
                publishers[channel_id] = self._publisher(node, route)
            self._await_subscribers(publishers.values())
            self._began = time.monotonic()
            while not self._stop.is_set():
                published = self._play_once(node, publishers)
                if self._stop.is_set():
                    break
                with self._lock:
                    self._loops += 1
                if not self.loop or not published:
                    break
        finally:
            self._ended = time.monotonic()
            for publisher in publishers.values():
                publisher.close()
        return self.stats

    def stop(self) -> None:
        """Make :meth:`run` return after the message it is publishing (from any thread)."""
        self._stop.set()

    @property
    def stats(self) -> PlayerStats:
        """What was published so far."""
        with self._lock:
            channels = tuple(c.freeze() for c in self._counters.values())
            position, loops = self._position, self._loops
        end = self._ended or time.monotonic()
        elapsed = 0.0 if self._began is None else end - self._began
        info = self._info
        duration = (
            (info.end_ns - info.start_ns) / 1e9
            if info.start_ns is not None and info.end_ns is not None
            else 0.0
        )
        return PlayerStats(self.path, elapsed, position, duration, loops, channels)

    def _publisher(self, node: Node, route: _Route) -> Publisher:
        return node.raw_publisher(route.topic, route.type, route.md5)

    def _await_subscribers(self, publishers: Iterable[Publisher]) -> None:
        deadline = time.monotonic() + self.wait_for_subscribers
        for publisher in publishers:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or self._stop.is_set():
                return
            publisher.wait_for_subscribers(remaining)

    def _play_once(self, node: Node, publishers: dict[int, Publisher]) -> int:
        origin: int | None = self._start_ns()
        file_start = self._info.start_ns
        wall_origin = time.monotonic()
        published = 0
        for schema, channel, message in self._messages():
            if self._stop.is_set():
                break
            publisher = publishers.get(channel.id)
            if publisher is None:  # unindexed file: routes are found as channels appear
                route = self._route(channel, schema)
                publisher = publishers[channel.id] = self._publisher(node, route)
                waited = time.monotonic()
                self._await_subscribers([publisher])
                wall_origin += time.monotonic() - waited  # the schedule starts after the wait
            if origin is None:
                origin = message.log_time
            if file_start is None:
                file_start = message.log_time
            if self.rate > 0:
                delay = wall_origin + (message.log_time - origin) / 1e9 / self.rate
                delay -= time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    break
            publisher.publish_raw(message.data)
            published += 1
            with self._lock:
                counter = self._counters.get(channel.id)
                if counter is None:
                    counter = self._counters[channel.id] = _Counter(
                        publisher.topic, publisher.type.name, publisher.type.md5
                    )
                counter.messages += 1
                counter.bytes += len(message.data)
                self._position = (message.log_time - file_start) / 1e9
        return published


def _definition_md5(schema: Schema) -> str:
    """md5 of a ros1msg schema, computed from its definition text (for files without md5sum)."""
    from rosbags.typesys import Stores, get_typestore
    from rosbags.typesys.msg import get_types_from_msg

    name = schema.name
    store_name = name if name.count("/") == 2 else "/msg/".join(name.split("/", 1))
    try:
        store = get_typestore(Stores.EMPTY)
        store.register(get_types_from_msg(schema.data.decode(), store_name))
        _, md5 = store.generate_msgdef(store_name)
    except Exception:  # noqa: BLE001 - any parse failure means "no md5 from this schema"
        return ""
    return str(md5)


def _describe(exc: BaseException) -> str:
    return str(exc) or type(exc).__name__
