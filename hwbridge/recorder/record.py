"""Recording graph topics into an MCAP file (see :mod:`hwbridge.recorder`)."""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Final, Literal

from mcap.exceptions import McapError
from mcap.writer import CompressionType, Writer

from hwbridge._version import __version__
from hwbridge.errors import HwBridgeError, UnknownTypeError
from hwbridge.graph.core import ANY_TYPE, RawMessage
from hwbridge.graph.names import resolve_name
from hwbridge.recorder.common import (
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    ChannelCounter,
    RecorderStats,
    RecordingError,
)

if TYPE_CHECKING:
    from hwbridge.graph import Graph, GraphEntity, Node, Subscriber
    from hwbridge.msg import TypeRegistry

log = logging.getLogger("hwbridge.recorder")

Compression = Literal["zstd", "lz4", "none"]
COMPRESSIONS: Final[dict[str, CompressionType]] = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}
"""Chunk compressions the ``mcap`` writer offers (it depends on zstandard and lz4)."""

PROFILE: Final = "ros1"
_SEQUENCE_MODULUS: Final = 2**32  # MCAP sequence numbers are uint32


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


FLUSH_EVERY: Final = 1.0
"""Seconds at most between two flushes of a recording's file while messages come: what a
recorder killed without finishing its file loses."""


class Recorder:
    """Records topics of a graph into an MCAP file.

    ``topics`` names the topics to record; ``None`` (or empty) records every topic that has a
    publisher, including those that appear while recording. Recording ends by :meth:`stop`; after
    ``limit`` messages or ``duration`` seconds it stops taking messages and :meth:`wait` returns.
    Messages go from Zenoh's threads through a queue of at most ``buffer_bytes`` to one writer
    thread; what does not fit is dropped and counted in ``stats.dropped``. The writer ends its
    chunk and flushes the file at least every ``flush_every`` seconds while messages come
    (None: only when a chunk reaches ``chunk_size``), so that a recorder killed without a chance
    to finish the file (SIGKILL, a crash) leaves a file that plays up to that point.
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
        flush_every: float | None = FLUSH_EVERY,
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
        if flush_every is not None and not flush_every > 0:
            raise RecordingError(f"flush_every must be positive seconds, got {flush_every:g}")
        self.graph = graph
        self.path = Path(path)
        self.topics: tuple[str, ...] = tuple(dict.fromkeys(resolve_name(t) for t in topics or ()))
        self.compression: Compression = compression
        self.duration = duration
        self.limit = limit
        self.overwrite = overwrite
        self.chunk_size = chunk_size
        self.flush_every = flush_every
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
        self._counters: dict[tuple[str, str, str], ChannelCounter] = {}
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
                self.graph.forget(self._watch)
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
        every = self.flush_every
        flushed = time.monotonic()
        # every while messages written since the last flush wait for one, else None: how long
        # the queue is waited on, and whether there is anything to flush
        flush_wait: float | None = None
        try:
            while True:
                try:
                    item = self._queue.get(timeout=flush_wait)
                except queue.Empty:  # quiet since: what is written goes to the file now
                    item = None
                if item is _STOP:
                    break
                if self._error is not None:
                    continue  # keep draining; the file is already failed
                try:
                    if isinstance(item, _Subscribe):
                        self._subscribe_discovered(item.topic)
                    elif item is not None:
                        assert isinstance(item, tuple)
                        received, message = item
                        self._write(writer, received, message)
                        flush_wait = every
                    if flush_wait is not None and time.monotonic() - flushed >= flush_wait:
                        writer.flush()  # type: ignore[no-untyped-call]
                        flushed, flush_wait = time.monotonic(), None
                except Exception as exc:  # noqa: BLE001 - disk full, I/O errors: reported by stop()
                    # stop() raises it, in the same words: an error logged here was said twice
                    log.info("recording to %s failed: %s", self.path, exc)
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
            self._counters[(message.topic, message.type, message.md5)] = ChannelCounter(
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
