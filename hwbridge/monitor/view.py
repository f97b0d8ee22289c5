"""``hwbridge monitor``'s picture of a :class:`~hwbridge.monitor.model.Snapshot`, with rich:
a boards table, a topics table and the last log lines, what a user checks first when "the robot
is not moving" (is the board connected? do its topics flow? are frames being lost?)."""

from __future__ import annotations

import time
from typing import Any

from rich.console import Group
from rich.table import Table
from rich.text import Text

from hwbridge.monitor.model import WINDOW, BoardRow, Snapshot

__all__ = ["render"]

_STATE_STYLES = {"connected": "bold green", "connecting": "yellow", "detecting": "yellow"}
_LEVEL_STYLES = {"WARN": "yellow", "ERROR": "bold red", "FATAL": "bold red", "STALE": "yellow"}


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


def boards_table(snapshot: Snapshot) -> Table:
    table = Table(title="boards", title_justify="left", expand=True, header_style="bold")
    for column in ("board", "link", "protocol", "state", "rx", "tx", "frames in/out"):
        table.add_column(column)
    for column in ("CRC errors", "drops", "retransmits", "RTT"):
        table.add_column(column, justify="right")
    for board in snapshot.boards:
        stats = board.stats
        state = Text(board.state, style=_STATE_STYLES.get(board.state, "bold red"))
        if board.error:
            state = Text(f"no answer: {board.error}", style="bold red")
        table.add_row(
            board.name,
            board.url,
            board.protocol,
            state,
            _rate(board.rx_rate),
            _rate(board.tx_rate),
            f"{_count(stats, 'frames_received')}/{_count(stats, 'frames_sent')}",
            _count(stats, "crc_errors"),
            str(board.drops),
            _count(stats, "retransmits"),
            _rtt(board),
        )
    if not snapshot.boards:
        table.add_row("(no boards: is a bridge running on this endpoint?)", *[""] * 10)
    return table


def topics_table(snapshot: Snapshot) -> Table:
    table = Table(
        title=f"topics (rates over {WINDOW:g} s)",
        title_justify="left",
        expand=True,
        header_style="bold",
    )
    table.add_column("topic")
    table.add_column("type")
    table.add_column("rate", justify="right")
    table.add_column("bandwidth", justify="right")
    table.add_column("messages", justify="right")
    table.add_column("pubs/subs", justify="right")
    for topic in snapshot.topics:
        rate = Text(f"{topic.rate:.1f} Hz", style="dim" if topic.rate == 0 else "")
        table.add_row(
            topic.name,
            topic.type,
            rate,
            _rate(topic.bandwidth),
            str(topic.messages),
            f"{topic.publishers}/{topic.subscribers}",
        )
    return table


def log_table(snapshot: Snapshot) -> Table:
    table = Table(
        title="last log lines (/rosout, /diagnostics)",
        title_justify="left",
        expand=True,
        show_header=False,
    )
    table.add_column("time", no_wrap=True)
    table.add_column("level", no_wrap=True)
    table.add_column("source", no_wrap=True)
    table.add_column("text")
    for line in snapshot.log:
        table.add_row(
            time.strftime("%H:%M:%S", time.localtime(line.stamp)),
            Text(line.level, style=_LEVEL_STYLES.get(line.level, "")),
            line.source,
            line.text,
        )
    if not snapshot.log:
        table.add_row("", "", "", Text("(nothing logged yet)", style="dim"))
    return table


def render(snapshot: Snapshot) -> Group:
    """The whole picture of one snapshot."""
    title = Text.assemble(
        ("hwbridge monitor", "bold"),
        f"  {snapshot.endpoint}  {time.strftime('%H:%M:%S', time.localtime(snapshot.time))}",
        ("  Ctrl-C quits", "dim"),
    )
    return Group(title, boards_table(snapshot), topics_table(snapshot), log_table(snapshot))
