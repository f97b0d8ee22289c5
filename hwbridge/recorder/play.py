"""Playing an MCAP file back onto the graph (see :mod:`hwbridge.recorder`)."""

from __future__ import annotations

import contextlib
import logging
import struct
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel, Message, Schema
from mcap.summary import Summary

from hwbridge.errors import HwBridgeError
from hwbridge.graph.discovery import close_names
from hwbridge.graph.names import resolve_name
from hwbridge.recorder.common import (
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    ChannelCounter,
    PlayerStats,
    RecordingError,
    describe,
)

if TYPE_CHECKING:
    from hwbridge.graph import Graph, Node, Publisher

log = logging.getLogger("hwbridge.recorder")


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
    when the Player is made: RecordingError if it is not MCAP or not ROS 1 encoded, or if none of
    ``topics`` is in it (naming the recorded topics spelt alike). Those of ``topics`` that are
    not in it are :attr:`missing` (for a caller to warn of), the file's topics :attr:`recorded`.
    A file with no summary (not closed cleanly) tells neither before it is played: they are
    known once :meth:`run` has read it to its end (:attr:`checked` says when), and if none of
    ``topics`` was in it, that :meth:`run` raises the RecordingError. Otherwise :meth:`run` then
    calls ``on_checked`` (in its thread, before a ``loop``'s next pass), the caller's moment to
    warn of :attr:`missing` while a loop plays on.
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
        on_checked: Callable[[], object] | None = None,
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
        self.on_checked = on_checked
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._counters: dict[int, ChannelCounter] = {}
        self._position = 0.0
        self._loops = 0
        self._began: float | None = None
        self._ended: float | None = None
        self.missing: tuple[str, ...] = ()
        """Topics asked for that are not in the file."""
        self.recorded: tuple[str, ...] = ()
        """The file's topics, sorted."""
        self.checked = False
        """Whether :attr:`missing` and :attr:`recorded` are known: from the file's summary, or
        for a file without one, once a pass has read it to its end."""
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
            except (McapError, struct.error) as exc:  # struct.error: shorter than MCAP's magic
                why = str(exc) or ("it is empty" if stream.seek(0, 2) == 0 else "")
                raise RecordingError(
                    f"{self.path} is not an MCAP file" + (f" ({why})" if why else "")
                ) from exc
            try:
                summary = reader.get_summary()
            except (McapError, struct.error, ValueError, OSError) as exc:
                log.warning(
                    "%s has no readable summary (%s): it was probably not closed cleanly; "
                    "playing the messages it holds in file order",
                    self.path,
                    describe(exc),
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
        self._checked(channel.topic for channel in summary.channels.values())
        if self._none_in_file:
            raise self._none_found()
        for channel in summary.channels.values():
            if wanted is None or channel.topic in wanted:
                schema = summary.schemas.get(channel.schema_id)
                info.routes[channel.id] = self._route(channel, schema)
        return info

    @property
    def _none_in_file(self) -> bool:
        """Topics were asked for, and the file (as far as it is known) holds none of them."""
        return self.topics is not None and len(self.missing) == len(self.topics)

    def _none_found(self) -> RecordingError:
        """The error for a file that holds none of :attr:`topics` (all :attr:`missing`)."""
        present = self.recorded
        close = dict.fromkeys(c for t in self.missing for c in close_names(t, present))
        hint = f"; did you mean {', '.join(close)}?" if close else ""
        return RecordingError(
            f"none of the topics {', '.join(self.missing)} is in {self.path}{hint} "
            f"(it has {', '.join(present) or 'no topics'})"
        )

    def _checked(self, present: Iterable[str]) -> None:
        """The file's topics, once known: from its summary, or (a file without one) once a pass
        has read it to its end."""
        if self.checked:
            return
        self.recorded = tuple(sorted(set(present)))
        if self.topics is not None:
            self.missing = tuple(t for t in self.topics if t not in self.recorded)
            for topic in self.missing:
                log.info("topic %s is not in %s", topic, self.path)
        self.checked = True

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
            md5 = definition_md5(schema)
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
            present: set[str] = set()
            bounds: list[int] = []
            try:
                yield from self._skip(self._unindexed(stream, present, bounds))
            except (McapError, struct.error, ValueError, OSError) as exc:
                if not self.checked:  # said on the first pass, not on each of a loop's
                    log.warning(
                        "%s ends early (%s); played what it holds", self.path, describe(exc)
                    )
            # read to its end (a pass stopped early never gets here): its topics and its length
            if bounds and self._info.start_ns is None:
                self._info.start_ns, self._info.end_ns = bounds
            self._checked(present)

    def _unindexed(
        self, stream: IO[bytes], present: set[str], bounds: list[int]
    ) -> Iterator[tuple[Schema | None, Channel, Message]]:
        """The selected messages of a file without a summary, in file order; the topics of all
        its messages are added to ``present`` as they are read, and ``bounds`` holds the first
        and last log time of them (empty until one is read)."""
        wanted = None if self.topics is None else set(self.topics)
        for item in NonSeekingReader(stream).iter_messages(log_time_order=False):
            present.add(item[1].topic)
            log_time = item[2].log_time
            if bounds:
                bounds[0] = min(bounds[0], log_time)
                bounds[1] = max(bounds[1], log_time)
            else:
                bounds += (log_time, log_time)
            if wanted is None or item[1].topic in wanted:
                yield item

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
        """Play the file (once, or until :meth:`stop` with ``loop``); returns the final stats.
        RecordingError if the file, having no summary, turned out to hold none of ``topics``."""
        node = self.graph.node(self.node_name)
        publishers: dict[int, Publisher] = {}
        try:
            for channel_id, route in self._info.routes.items():
                publishers[channel_id] = self._publisher(node, route)
            self._await_subscribers(publishers.values())
            self._began = time.monotonic()
            while not self._stop.is_set():
                known = self.checked
                published = self._play_once(node, publishers)
                if self._stop.is_set():
                    break
                with self._lock:
                    self._loops += 1
                if self.checked and not known and not self._none_in_file and self.on_checked:
                    self.on_checked()  # a file without a summary, read to its end once
                if not self.loop or not published:
                    break
        finally:
            self._ended = time.monotonic()
            for publisher in publishers.values():
                publisher.close()
        if self._none_in_file:
            raise self._none_found()  # a file without a summary, read to its end
        return self.stats

    def stop(self) -> None:
        """Make :meth:`run` return after the message it is publishing (from any thread)."""
        self._stop.set()

    @property
    def stopped(self) -> bool:
        """Whether :meth:`stop` was called."""
        return self._stop.is_set()

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
            else None
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
            publisher.wait_for_subscribers(remaining, self._stop)

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
                    counter = self._counters[channel.id] = ChannelCounter(
                        publisher.topic, publisher.type.name, publisher.type.md5
                    )
                counter.messages += 1
                counter.bytes += len(message.data)
                self._position = (message.log_time - file_start) / 1e9
        return published


def definition_md5(schema: Schema) -> str:
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
