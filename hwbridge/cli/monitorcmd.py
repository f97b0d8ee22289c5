"""``hwbridge monitor``: a live terminal view of the running bridge (rich)."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Annotated

import typer

from hwbridge.cli.common import emit_json, open_graph

if TYPE_CHECKING:
    from rich.console import RenderableType

__all__ = ["monitor"]


def monitor(
    ctx: typer.Context,
    interval: Annotated[
        float, typer.Option("--interval", min=0.1, help="Seconds between refreshes.")
    ] = 1.0,
    log_lines: Annotated[
        int, typer.Option("--log-lines", min=1, help="Log lines to keep on screen.")
    ] = 8,
    once: Annotated[
        bool,
        typer.Option(
            "--once",
            help="Print one picture after --wait seconds and exit (no live screen; for scripts "
            "and terminals without cursor control).",
        ),
    ] = False,
    wait: Annotated[
        float,
        typer.Option("--wait", min=0.0, help="With --once: seconds of measuring before printing."),
    ] = 3.0,
    width: Annotated[
        int | None,
        typer.Option("--width", min=40, help="Columns to draw (default: the terminal's)."),
    ] = None,
    as_json: Annotated[
        bool,
        typer.Option(
            "--json",
            help="One JSON object per refresh on stdout (with --once: one object), for scripts.",
        ),
    ] = False,
) -> None:
    """A live terminal view of the running bridge: boards, link state, topics, rates, logs.

    Boards come with their link state, bytes per second, frames, CRC errors, drops,
    retransmissions and round-trip time; topics with their rates and bandwidth; then the last
    lines of /rosout and the diagnostics that are not OK. In a narrow terminal the less
    important columns go first; on the live screen, topics and log lines are cut to its height.
    """
    from rich.console import Console
    from rich.live import Live

    from hwbridge.monitor.model import Monitor
    from hwbridge.monitor.view import render

    console = Console(width=width, soft_wrap=False)
    with open_graph(ctx) as graph, Monitor(graph, log_lines=log_lines) as watching:
        try:
            if once:
                deadline = time.monotonic() + wait
                while time.monotonic() < deadline:  # polls give the boards' byte rates history
                    watching.poll()
                    time.sleep(max(0.0, min(0.5, deadline - time.monotonic())))
                snapshot = watching.poll()
                if as_json:
                    emit_json(snapshot.to_json())
                else:
                    console.print(render(snapshot, console.width))
            elif as_json or not console.is_terminal:  # a pipe or a file: one picture per interval
                while True:
                    snapshot = watching.poll()
                    if as_json:
                        emit_json(snapshot.to_json())
                    else:
                        console.print(render(snapshot, console.width))
                    time.sleep(interval)
            else:

                def picture() -> RenderableType:
                    return render(watching.poll(), console.width, console.height)

                with Live(picture(), console=console, screen=True, auto_refresh=False) as live:
                    while True:
                        time.sleep(interval)
                        live.update(picture(), refresh=True)
        except KeyboardInterrupt:
            pass
