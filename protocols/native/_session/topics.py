"""The topic table of a native session: the board announces it, the host checks each entry.

PROTOCOL.md 2.6 (BOARD_INFO, TOPIC, TABLE_END, TOPIC_ACK, READY). :class:`HostTable` is the
host's side (with the type check), :class:`DeviceTable` the board's.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hwbridge.protocols.native._control.common import TopicStatus
from hwbridge.protocols.native._hotpath import CONFIGURING
from hwbridge.protocols.native._session.config import (
    BoardInfo,
    TopicEntry,
    TopicMismatchError,
    TypeCheck,
)
from hwbridge.protocols.native._session.core import SessionCore, _truncate
from hwbridge.protocols.native._session.events import TopicAnnounced
from hwbridge.protocols.native.control import (
    BoardInfoMsg,
    ReadyMsg,
    TableEndMsg,
    TopicAckMsg,
    TopicMsg,
)


class HostTable(SessionCore[Any]):
    """The host's side: the board's identity, its entries, and which were accepted."""

    _type_check: TypeCheck | None
    _board: BoardInfo | None
    _announced: dict[int, TopicEntry]
    _topics: dict[int, TopicEntry]

    @property
    def board(self) -> BoardInfo | None:
        """The connected board, None before BOARD_INFO."""
        return self._board

    @property
    def topics(self) -> Mapping[int, TopicEntry]:
        """Accepted entries by channel (current session)."""
        return dict(self._topics)

    def _entry(self, channel: int) -> TopicEntry | None:
        return self._topics.get(channel)

    def _board_entry(self, channel: int) -> TopicEntry | None:
        return self._announced.get(channel)

    def _on_topic(self, msg: TopicMsg) -> None:
        if self._state is not CONFIGURING:
            self._protocol_error(f"TOPIC for channel {msg.channel} after the table ended")
            return
        problem = ""
        entry: TopicEntry | None = None
        try:
            entry = TopicEntry.from_msg(msg)
        except ValueError as exc:
            problem = str(exc)
        if entry is not None and entry.channel in self._announced:
            other = self._announced[entry.channel]
            problem = f"channel {entry.channel} announced twice ({other.name} and {entry.name})"
        if entry is None or problem:
            self._protocol_error(f"the board announced an invalid entry: {problem}")
            detail = _truncate(problem, self._peer_max - 19).decode("utf-8")
            self._send_control(TopicAckMsg(msg.channel, TopicStatus.INVALID, "", detail))
            return
        self._announced[entry.channel] = entry
        expected = self._type_check(entry) if self._type_check is not None else None
        if expected is not None and (
            expected.type_name != entry.type_name or expected.md5.lower() != entry.md5
        ):
            self._c.protocol_errors += 1
            self._error(
                TopicMismatchError(
                    entry.name,
                    entry.channel,
                    entry.type_name,
                    entry.md5,
                    expected.type_name,
                    expected.md5,
                )
            )
            detail = _truncate(expected.type_name, self._peer_max - 19).decode("utf-8")
            md5 = expected.md5.lower() if len(expected.md5) == 32 else ""
            self._send_control(TopicAckMsg(entry.channel, TopicStatus.MISMATCH, md5, detail))
            return
        self._topics[entry.channel] = entry
        self._events.append(TopicAnnounced(entry))
        self._send_control(TopicAckMsg(entry.channel, TopicStatus.ACCEPTED))

    def _on_table_end(self, msg: TableEndMsg) -> None:
        if self._state is not CONFIGURING:
            self._protocol_error("TABLE_END after the table ended")
            return
        if msg.count != len(self._announced):
            self._protocol_error(
                f"the board announced {len(self._announced)} entries but TABLE_END counts "
                f"{msg.count}"
            )
        board = self._board
        if board is None:
            self._protocol_error("the board sent TABLE_END without BOARD_INFO")
            board = BoardInfo("", b"", "")
            self._board = board
        self._send_control(ReadyMsg(len(self._topics)))
        self._connect(board, tuple(self._topics.values()))


class DeviceTable(SessionCore[Any]):
    """The board's side: its whole table, announced once per session, and the host's verdicts."""

    _board: BoardInfo
    _table: dict[int, TopicEntry]
    _accepted: set[int]

    @property
    def board(self) -> BoardInfo:
        """This board."""
        return self._board

    @property
    def topics(self) -> Mapping[int, TopicEntry]:
        """This board's whole table by channel."""
        return dict(self._table)

    @property
    def accepted(self) -> frozenset[int]:
        """Channels the host accepted in the current session."""
        return frozenset(self._accepted)

    def _entry(self, channel: int) -> TopicEntry | None:
        return self._table.get(channel) if channel in self._accepted else None

    def _board_entry(self, channel: int) -> TopicEntry | None:
        return self._table.get(channel)

    def _on_established(self) -> None:
        self._accepted.clear()
        entries = list(self._table.values())
        board = self._board
        self._send_control(
            BoardInfoMsg(len(entries), board.name, board.unique_id, board.firmware_version)
        )
        for entry in entries:
            self._send_control(entry.to_msg())
        self._send_control(TableEndMsg(len(entries)))

    def _on_topic_ack(self, msg: TopicAckMsg) -> None:
        entry = self._table.get(msg.channel)
        if entry is None:
            self._protocol_error(f"TOPIC_ACK for channel {msg.channel}, which this board lacks")
            return
        if msg.status == TopicStatus.ACCEPTED:
            self._accepted.add(msg.channel)
        elif msg.status == TopicStatus.MISMATCH:
            self._c.protocol_errors += 1
            self._error(
                TopicMismatchError(
                    entry.name, entry.channel, entry.type_name, entry.md5, msg.detail, msg.host_md5
                )
            )
        else:
            self._protocol_error(
                f"the host refused {entry.name} (channel {entry.channel}): {msg.detail}"
            )

    def _on_ready(self, msg: ReadyMsg) -> None:
        if self._state is not CONFIGURING:
            return
        if msg.accepted != len(self._accepted):
            self._protocol_error(
                f"READY counts {msg.accepted} accepted entries, this board saw "
                f"{len(self._accepted)}"
            )
        topics = tuple(self._table[c] for c in self._table if c in self._accepted)
        self._connect(self._board, topics)
