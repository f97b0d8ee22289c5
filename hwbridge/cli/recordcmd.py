"""``hwbridge record`` and ``hwbridge play``: MCAP recordings of graph topics.

``app`` holds both commands; the root adds them at top level with ``app.add_typer(recordcmd.app)``.
SIGINT (Ctrl-C) and SIGTERM end a recording or a playback cleanly (a second one aborts at once).
Progress goes to stderr: a live table on a terminal, a plain line every few seconds otherwise.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from collections.abc import Callable, Iterator
from datetime import datetime
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from hwbridge.cli.common import (
    Context,
    get_registry,
    open_graph,
    stderr_console,
    warnings_as_notes,
)

if TYPE_CHECKING:
    from rich.console import RenderableType

    from hwbridge.graph import Graph
    from hwbridge.recorder import ChannelStats, Player, PlayerStats, Recorder, RecorderStats

__all__ = ["CompressionChoice", "app", "play", "record"]

app = typer.Typer(help="Record topics to MCAP files and play them back.")

PLAIN_INTERVAL = 2.0
"""Seconds between progress lines when stderr is not a terminal."""


class CompressionChoice(str, Enum):
    """Chunk compression of the MCAP file."""

    zstd = "zstd"
    lz4 = "lz4"
    none = "none"


EndpointOpt = Annotated[
    str | None,
    typer.Option(
        "--endpoint",
        help="Zenoh endpoint of the running bridge; overrides the global --endpoint and "
        "HWBRIDGE_ENDPOINT.",
    ),
]
QuietOpt = Annotated[bool, typer.Option("-q", "--quiet", help="No progress and no summary.")]


# ---------------------------------------------------------------------- record
@app.command("record")
def record(
    ctx: typer.Context,
    topics: Annotated[
        list[str] | None,
        typer.Argument(metavar="TOPIC", help="Topics to record; none means every topic."),
    ] = None,
    output: Annotated[
        Path | None,
        typer.Option(
            "-o",
            "--output",
            dir_okay=False,
            help="MCAP file to write (default hwbridge_DATE-TIME.mcap).",
        ),
    ] = None,
    all_topics: Annotated[
        bool,
        typer.Option("-a", "--all", help="Record every topic, including ones that appear later."),
    ] = False,
    duration: Annotated[
        float | None, typer.Option("--duration", min=0.001, help="Stop after SECONDS.")
    ] = None,
    limit: Annotated[
        int | None, typer.Option("-l", "--limit", min=1, help="Stop after N messages.")
    ] = None,
    compression: Annotated[
        CompressionChoice, typer.Option("--compression", help="Chunk compression.")
    ] = CompressionChoice.zstd,
    force: Annotated[
        bool, typer.Option("-f", "--force", help="Overwrite the output file if it exists.")
    ] = False,
    endpoint: EndpointOpt = None,
    quiet: QuietOpt = False,
) -> None:
    """Record topics to an MCAP file (ROS 1 profile) until Ctrl-C, --duration or --limit.

    A named topic that nothing publishes after 2 s of discovery gets a warning naming the
    published topics spelt alike, and is still recorded if a publisher appears. The file is
    written out at least every second: killed without finishing it, the recorder leaves what
    it had until then (play reads such a file).
    """
    from hwbridge.cli.livetopics import name_argument
    from hwbridge.recorder import Recorder

    warnings_as_notes()  # the recorder's, as this command's own
    if topics and all_topics:
        raise typer.BadParameter("give topics or --all, not both")
    topics = [name_argument(topic) for topic in topics or ()]
    path = output or Path(datetime.now().strftime("hwbridge_%Y-%m-%d-%H-%M-%S.mcap"))
    interrupted = threading.Event()
    # Start-up (attaching, loading the message types) is not shielded: Ctrl-C there ends the
    # command at once (130) before any file exists. From creating the file on, a signal ends
    # the recording through ``interrupted`` and the file is finished properly.
    with _open(ctx, endpoint) as graph:
        check = _PublisherCheck(graph) if topics else None
        recorder = Recorder(
            graph,
            path,
            topics or None,
            compression=compression.value,
            duration=duration,
            limit=limit,
            overwrite=force,
        )
        with _stop_on_signals(interrupted.set):
            recorder.start()
            try:
                with _progress(
                    lambda: _record_table(recorder.stats, recorder.topics),
                    lambda: _record_line(recorder.stats, recorder.topics),
                    quiet,
                ):
                    while not interrupted.is_set() and not recorder.done:
                        interrupted.wait(0.1)
                        if check is not None:
                            check.after_grace(recorder)
                if check is not None:  # ended within the grace: what discovery has seen by now
                    check.now(recorder)
                if interrupted.is_set() and not quiet:
                    stderr_console().print(f"finishing {path}...", highlight=False)
            finally:
                stats = recorder.stop()
    if not quiet:
        channels = _with_named(stats.channels, recorder.topics)
        _print_summary("recorded", "to", stats.path, stats.elapsed, channels)
        if stats.dropped:
            typer.echo(
                f"warning: dropped {stats.dropped} messages (the disk did not keep up)", err=True
            )


class _PublisherCheck:
    """Warns of named topics that nothing publishes, once: when discovery has had GRACE
    seconds (as ``topic echo`` gives it), or when the recording ends before that. One line per
    topic, naming the published topics spelt alike; recording goes on (a publisher may come)."""

    def __init__(self, graph: Graph) -> None:
        from hwbridge.graph.discovery import LiveGraph

        self.live = LiveGraph(graph)
        self.started = time.monotonic()
        self.done = False

    def after_grace(self, recorder: Recorder) -> None:
        """Warn if GRACE seconds have passed (and not yet warned)."""
        from hwbridge.cli.livetopics import GRACE

        if time.monotonic() - self.started >= GRACE:
            self.now(recorder)

    def now(self, recorder: Recorder) -> None:
        """Warn of the topics unpublished now (unless already done)."""
        from hwbridge.cli.livetopics import note
        from hwbridge.graph.discovery import did_you_mean

        if self.done:
            return
        self.done = True
        # a topic heard is published, whether or not discovery has told yet
        published = self.live.published() | {c.topic for c in recorder.stats.channels}
        for topic in recorder.topics:
            if topic not in published:
                note(
                    f"warning: no publisher of {topic} yet{did_you_mean(topic, published)} "
                    "(recording it if one appears)"
                )


def _with_named(
    channels: tuple[ChannelStats, ...], topics: tuple[str, ...]
) -> tuple[ChannelStats, ...]:
    """``channels`` and, for each of the named ``topics`` with no message yet, an empty one (so
    a misspelt or silent topic shows as 0 messages, not as nothing)."""
    from hwbridge.recorder import ChannelStats

    heard = {c.topic for c in channels}
    return channels + tuple(ChannelStats(t, "", "") for t in topics if t not in heard)


def _record_table(stats: RecorderStats, topics: tuple[str, ...]) -> RenderableType:
    from rich.table import Table

    table = Table(
        title=f"recording {stats.path}",
        caption=f"{stats.elapsed:.1f} s, {stats.messages} messages, {_size(stats.bytes)}"
        + (f", {stats.dropped} dropped" if stats.dropped else ""),
        title_justify="left",
        caption_justify="left",
        box=None,
    )
    table.add_column("topic")
    table.add_column("type")
    table.add_column("messages", justify="right")
    table.add_column("size", justify="right")
    for channel in _with_named(stats.channels, topics):
        kind = channel.type if channel.has_schema else f"{channel.type or '?'} (no schema)"
        table.add_row(channel.topic, kind, str(channel.messages), _size(channel.bytes))
    return table


def _record_line(stats: RecorderStats, named: tuple[str, ...]) -> str:
    topics = ", ".join(f"{c.topic} {c.messages}" for c in _with_named(stats.channels, named))
    dropped = f", {stats.dropped} dropped" if stats.dropped else ""
    return (
        f"recording {stats.path}: {stats.elapsed:.1f} s, {stats.messages} messages, "
        f"{_size(stats.bytes)}{dropped}" + (f" ({topics})" if topics else "")
    )


# ---------------------------------------------------------------------- play
@app.command("play")
def play(
    ctx: typer.Context,
    file: Annotated[
        Path,
        typer.Argument(
            metavar="FILE", exists=True, dir_okay=False, help="MCAP file (ROS 1 encoded)."
        ),
    ],
    topic_args: Annotated[
        list[str] | None,
        typer.Argument(metavar="TOPIC", help="Play only these topics (as --topics)."),
    ] = None,
    rate: Annotated[
        float,
        typer.Option("-r", "--rate", min=0.0, help="Time scale; 0 plays as fast as possible."),
    ] = 1.0,
    loop: Annotated[
        bool, typer.Option("-l", "--loop", help="Start over at the end, until Ctrl-C.")
    ] = False,
    topics: Annotated[
        list[str] | None,
        typer.Option(
            "--topics", help="Play only these topics (repeatable; comma-separated accepted)."
        ),
    ] = None,
    start: Annotated[
        float, typer.Option("-s", "--start", min=0.0, help="Skip SECONDS from the beginning.")
    ] = 0.0,
    wait: Annotated[
        float,
        typer.Option(
            "--wait", min=0.0, help="Seconds to wait for subscribers before the first message."
        ),
    ] = 1.0,
    endpoint: EndpointOpt = None,
    quiet: QuietOpt = False,
) -> None:
    """Publish the messages of an MCAP file with their recorded timing (scaled by --rate).

    A topic asked for that is not in the file gets a warning naming the recorded topics spelt
    alike; if none of them is, that is an error. A file not closed cleanly (no index) tells
    this only once it has been played to its end (with --loop, once its first pass ends). The
    summary lists every topic asked for, with its count, 0 or not."""
    from hwbridge.cli.livetopics import name_argument
    from hwbridge.recorder import Player

    warnings_as_notes()  # the player's, as this command's own
    selected = [
        name_argument(t) for item in [*(topics or ()), *(topic_args or ())] for t in _split(item)
    ]
    told = False  # of the topics not in the file

    def tell(played: bool) -> None:
        nonlocal told
        told = True
        _warn_missing(player, played=played)

    with _open(ctx, endpoint) as graph:
        player = Player(
            graph,
            file,
            rate=rate,
            loop=loop,
            topics=selected or None,
            start=start,
            wait_for_subscribers=wait,
            # a file without a summary tells its topics once read: a loop plays on after that
            on_checked=(lambda: tell(played=False)) if loop else None,
        )
        if player.checked:  # from the file's summary
            tell(played=False)
        with (
            _stop_on_signals(player.stop),
            _progress(
                lambda: _play_line(player.stats, rate, loop),
                lambda: _play_line(player.stats, rate, loop),
                quiet,
            ),
        ):
            stats = player.run()
        if not player.stopped:  # played to the end: let Zenoh send what is queued
            time.sleep(0.2)  # (after a signal, stopping promptly comes first)
    if not quiet:
        channels = _with_named(stats.channels, player.topics or ())
        _print_summary("played", "from", stats.path, stats.elapsed, channels)
    if not told:  # a file without a summary, played once
        tell(played=True)


def _warn_missing(player: Player, *, played: bool) -> None:
    """A warning for each topic asked for that is not in the player's file, naming the recorded
    topics spelt alike; ``played``: said once the playing has ended."""
    from hwbridge.cli.livetopics import note
    from hwbridge.graph.discovery import did_you_mean

    verb, others = ("was", "played") if played else ("is", "playing")
    for topic in player.missing:
        note(
            f"warning: {topic} {verb} not in {player.path}"
            f"{did_you_mean(topic, player.recorded)} ({others} the others)"
        )


def _split(item: str) -> list[str]:
    return [t for t in item.replace(",", " ").split() if t]


def _play_line(stats: PlayerStats, rate: float, loop: bool) -> str:
    speed = "as fast as possible" if rate == 0 else f"x{rate:g}"
    loops = f", pass {stats.loops + 1}" if loop else ""
    where = (
        f"{stats.position:.1f} s (no index: length known once played through)"
        if stats.duration is None
        else f"{stats.position:.1f} / {stats.duration:.1f} s"
    )
    return (
        f"playing {stats.path} ({speed}): {where}, "
        f"{stats.messages} messages, {_size(stats.bytes)}{loops}"
    )


# ---------------------------------------------------------------------- helpers
def _open(ctx: typer.Context, endpoint: str | None) -> Graph:
    """Attach to the graph, at ``endpoint`` if given (else as the global options say)."""
    if endpoint is None:
        return open_graph(ctx)
    from hwbridge.graph import Graph, GraphConfig

    options = ctx.find_root().obj
    domain = options.domain if isinstance(options, Context) else None
    graph = Graph(GraphConfig.attached([endpoint], domain))
    graph.registry = get_registry(ctx)
    return graph


def _stop_on_signals(on_stop: Callable[[], None]) -> contextlib.AbstractContextManager[None]:
    """Call ``on_stop`` on the first SIGINT or SIGTERM (the command then finishes through it);
    a second one ends the process (see :mod:`hwbridge.cli.stopping`)."""
    from hwbridge.cli.stopping import on_signal

    return on_signal(on_stop)


@contextlib.contextmanager
def _progress(
    render: Callable[[], RenderableType | str], line: Callable[[], str], quiet: bool
) -> Iterator[None]:
    """Live progress on stderr while the block runs."""
    if quiet:
        yield
        return
    if stderr_console().is_terminal:
        from rich.live import Live

        with Live(
            get_renderable=render, console=stderr_console(), refresh_per_second=4, transient=True
        ):
            yield
        return
    done = threading.Event()

    def report() -> None:
        while not done.wait(PLAIN_INTERVAL):
            sys.stderr.write(line() + "\n")
            sys.stderr.flush()

    thread = threading.Thread(target=report, name="hwbridge-progress", daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()


def _print_summary(
    verb: str, preposition: str, path: Path, elapsed: float, channels: tuple[ChannelStats, ...]
) -> None:
    messages = sum(c.messages for c in channels)
    size = sum(c.bytes for c in channels)
    topics = len({c.topic for c in channels if c.messages})
    lines = [
        f"{verb} {messages} messages ({_size(size)}) on {topics} topic{'s' * (topics != 1)} "
        f"in {elapsed:.1f} s {preposition} {path}"
    ]
    width = max((len(c.topic) for c in channels), default=0)
    type_width = max((len(c.type or "?") for c in channels), default=0)
    for c in channels:
        schema = "" if c.has_schema else " (no schema: type unknown to the registry)"
        lines.append(
            f"  {c.topic:<{width}}  {c.type or '?':<{type_width}}  {c.messages} messages, "
            f"{_size(c.bytes)}{schema}"
        )
    typer.echo("\n".join(lines), err=True)


def _size(count: float) -> str:
    if count < 1000:
        return f"{count:.0f} B"
    for unit in ("kB", "MB"):
        count /= 1000
        if count < 1000:
            return f"{count:.1f} {unit}"
    return f"{count / 1000:.1f} GB"
