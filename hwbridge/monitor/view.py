"""``hwbridge monitor``'s picture of a :class:`~hwbridge.monitor.model.Snapshot`, with rich:
a boards table, a topics table and the last log lines, what a user checks first when "the robot
is not moving" (is the board connected? do its topics flow? are frames being lost?).

The picture fits the width it is given: columns are laid out here, each as wide as its widest
cell, and the less important ones go (or take their short header) when the width runs out; a
line is never wrapped, and text too long for its place is shortened at a word, with "…". Given a
height too (the live screen), topics and log lines are cut to what fits, saying how many more.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rich.console import Group
from rich.text import Text

from hwbridge.monitor.model import WINDOW, BoardRow, Snapshot, TopicRow

__all__ = ["render"]

_STATE_STYLES = {"connected": "bold green", "connecting": "yellow", "detecting": "yellow"}
_LEVEL_STYLES = {"WARN": "yellow", "ERROR": "bold red", "FATAL": "bold red", "STALE": "yellow"}
_GAP = 2
_UNLIMITED = 10_000


def _rate(value: float | None, unit: str = "B/s") -> str:
    if value is None:
        return "-"
    for scale, prefix in ((1e6, "M"), (1e3, "k")):
        if value >= scale:
            return f"{value / scale:.1f} {prefix}{unit}"
    return f"{value:.0f} {unit}"


def _count(stats: dict[str, Any], key: str) -> str:
    value = stats.get(key)
    return "-" if value is None else str(value)


def _rtt(board: BoardRow) -> str:
    rtt = board.stats.get("rtt") or board.stats.get("srtt")
    return f"{float(rtt) * 1e3:.1f} ms" if isinstance(rtt, int | float) and rtt else "-"


def shorten(text: str, width: int) -> str:
    """``text`` in at most ``width`` columns: cut at the last space that leaves room for "…"
    (mid-word only when the first word alone is too long)."""
    if len(text) <= width:
        return text
    if width <= 1:
        return "…"[:width]
    cut = text[: width - 1]
    space = cut.rfind(" ")
    if space > width // 3:
        cut = cut[:space]
    return cut.rstrip(" ,;:") + "…"


@dataclass(frozen=True)
class _Column:
    header: str
    short: str
    cell: Callable[[Any], str | Text]
    right: bool = False
    required: bool = False


def _text(value: str | Text) -> Text:
    return value if isinstance(value, Text) else Text(value)


def _table(columns: list[_Column], rows: list[Any], width: int) -> list[Text]:
    """Header and rows of the columns that fit in ``width``, required ones first, the others
    while they fit (with their long headers if everything then fits, else the short ones)."""
    cells = [[_text(column.cell(row)) for row in rows] for column in columns]

    def widths(headers: list[str]) -> list[int]:
        return [
            max([len(header), *(len(cell.plain) for cell in column)])
            for header, column in zip(headers, cells, strict=True)
        ]

    chosen: list[int] = []
    headers: list[str] = []
    for long in (True, False):
        headers = [c.header if long else c.short for c in columns]
        sizes = widths(headers)
        chosen = [i for i, c in enumerate(columns) if c.required]
        for index, column in enumerate(columns):
            if column.required:
                continue
            trial = sorted([*chosen, index])
            if sum(sizes[i] for i in trial) + _GAP * (len(trial) - 1) <= width:
                chosen = trial
        if len(chosen) == len(columns):
            break
    sizes = widths(headers)
    # the first column (a name) gives way if the required ones alone are too wide
    spare = width - (sum(sizes[i] for i in chosen) + _GAP * (len(chosen) - 1))
    if spare < 0:
        sizes[chosen[0]] = max(4, sizes[chosen[0]] + spare)

    def line(parts: list[Text]) -> Text:
        out = Text(no_wrap=True, overflow="ellipsis")
        for n, i in enumerate(chosen):
            part = parts[i]
            if len(part.plain) > sizes[i]:
                part = Text(shorten(part.plain, sizes[i]), style=part.style)
            pad = " " * (sizes[i] - len(part.plain))
            if n:
                out.append(" " * _GAP)
            if columns[i].right:
                out.append(pad)
                out.append_text(part)
            else:
                out.append_text(part)
                if n < len(chosen) - 1:
                    out.append(pad)
        return out

    lines = [line([Text(h, style="bold") for h in headers])]
    lines += [line([column[r] for column in cells]) for r in range(len(rows))]
    return lines


def _state(board: BoardRow) -> Text:
    if board.error:
        return Text("no answer", style="bold red")
    return Text(board.state, style=_STATE_STYLES.get(board.state, "bold red"))


_BOARD_COLUMNS = [
    _Column("board", "board", lambda b: b.name, required=True),
    _Column("state", "state", _state, required=True),
    _Column("rx", "rx", lambda b: _rate(b.rx_rate), right=True),
    _Column("tx", "tx", lambda b: _rate(b.tx_rate), right=True),
    _Column("CRC errors", "crc", lambda b: _count(b.stats, "crc_errors"), right=True),
    _Column("drops", "drop", lambda b: str(b.drops), right=True),
    _Column("RTT", "RTT", _rtt, right=True),
    _Column("retransmits", "retx", lambda b: _count(b.stats, "retransmits"), right=True),
    _Column(
        "frames in/out",
        "frames",
        lambda b: f"{_count(b.stats, 'frames_received')}/{_count(b.stats, 'frames_sent')}",
        right=True,
    ),
    _Column("protocol", "proto", lambda b: b.protocol),
    _Column("link", "link", lambda b: b.url),
]

_TOPIC_COLUMNS = [
    _Column("topic", "topic", lambda t: t.name, required=True),
    _Column(
        "rate",
        "rate",
        lambda t: Text(f"{t.rate:.1f} Hz", style="dim" if t.rate == 0 else ""),
        right=True,
        required=True,
    ),
    _Column("bandwidth", "bw", lambda t: _rate(t.bandwidth), right=True),
    _Column("type", "type", lambda t: t.type),
    _Column("messages", "msgs", lambda t: str(t.messages), right=True),
    _Column("pubs/subs", "p/s", lambda t: f"{t.publishers}/{t.subscribers}", right=True),
]


def _title(text: str) -> Text:
    return Text(text, style="bold underline", no_wrap=True, overflow="ellipsis")


def boards_lines(snapshot: Snapshot, width: int) -> list[Text]:
    lines = [_title("boards")]
    if not snapshot.boards:
        note = "(no boards: is a bridge running on this endpoint?)"
        return [*lines, Text(shorten(note, width), style="dim")]
    lines += _table(_BOARD_COLUMNS, snapshot.boards, width)
    for board in snapshot.boards:
        if board.error:
            lines.append(Text(shorten(f"{board.name}: {board.error}", width), style="red"))
    return lines


def topics_lines(topics: list[TopicRow], hidden: int, width: int) -> list[Text]:
    lines = [_title(shorten(f"topics (rates over {WINDOW:g} s)", width))]
    if topics:
        lines += _table(_TOPIC_COLUMNS, topics, width)
    if hidden:
        lines.append(Text(shorten(f"… {hidden} more topics", width), style="dim"))
    return lines


def log_lines(snapshot: Snapshot, count: int, width: int) -> list[Text]:
    lines = [_title(shorten("last log lines (/rosout, /diagnostics)", width))]
    shown = snapshot.log[len(snapshot.log) - count :] if count else []
    for entry in shown:
        stamp = time.strftime("%H:%M:%S", time.localtime(entry.stamp))
        line = Text(no_wrap=True, overflow="ellipsis")
        line.append(f"{stamp} ")
        line.append(f"{entry.level:<5}", style=_LEVEL_STYLES.get(entry.level, ""))
        line.append(shorten(f" {entry.source}: {entry.text}", width - len(stamp) - 6))
        lines.append(line)
    if not snapshot.log:
        lines.append(Text("(nothing logged yet)", style="dim"))
    return lines


def render(snapshot: Snapshot, width: int | None = None, height: int | None = None) -> Group:
    """The whole picture of one snapshot, every line at most ``width`` columns (all columns
    when not given); in at most ``height`` lines when given (topics, then log lines, cut to
    fit)."""
    width = max(20, width or _UNLIMITED)
    clock = time.strftime("%H:%M:%S", time.localtime(snapshot.time))
    head = Text(no_wrap=True, overflow="ellipsis")
    head.append("hwbridge monitor", style="bold")
    rest = f"  {snapshot.endpoint}  {clock}"
    quit_hint = "  Ctrl-C quits"
    if 16 + len(rest) + len(quit_hint) <= width:
        head.append(rest)
        head.append(quit_hint, style="dim")
    else:
        head.append(shorten(rest, width - 16))
    boards = boards_lines(snapshot, width)
    topics = snapshot.topics
    logs = len(snapshot.log)
    hidden = 0
    if height is not None:
        # head, blank, boards, blank, topics title and header, blank, log title
        fixed = 1 + 1 + len(boards) + 1 + 1 + (1 if topics else 0) + 1 + 1
        room = max(0, height - fixed - (0 if snapshot.log else 1))
        if len(topics) + logs > room:
            logs = min(logs, max(1, room // 4), room)
            if len(topics) > room - logs:
                shown = max(0, room - logs - 1)  # and one line says how many more
                hidden = len(topics) - shown
                topics = topics[:shown]
            logs = min(len(snapshot.log), room - len(topics) - (1 if hidden else 0))
    parts: list[Text] = [head, Text(""), *boards, Text("")]
    parts += topics_lines(topics, hidden, width)
    parts += [Text(""), *log_lines(snapshot, logs, width)]
    if height is not None:
        parts = parts[:height]
    return Group(*parts)
