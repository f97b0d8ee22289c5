"""``hwbridge viz``: serve the running graph to Foxglove and Lichtblick (the Foxglove WebSocket
protocol)."""

from __future__ import annotations

import sys
from typing import Annotated

import typer

from hwbridge.cli.bridgecmd import wait_for_signal
from hwbridge.cli.common import open_graph

__all__ = ["viz"]


def viz(
    ctx: typer.Context,
    topic: Annotated[
        list[str] | None,
        typer.Option("--topic", "-t", help="Serve only this topic; repeatable (default: all)."),
    ] = None,
    port: Annotated[
        int,
        typer.Option("--port", "-p", min=0, max=65535, help="WebSocket port (0: any free one)."),
    ] = 8765,
    host: Annotated[
        str,
        typer.Option("--host", help="Address to listen on (0.0.0.0: every interface)."),
    ] = "127.0.0.1",
) -> None:
    """Serve the graph to Foxglove or Lichtblick over WebSocket until Ctrl-C.

    Topics (ROS 1 schemas), services to call, server time, and publishing from the viewer
    (Teleop).

    The first line printed is the URL to open (Open connection, Foxglove WebSocket);
    examples/foxglove/layout.json is a layout for the demo robot.
    """
    from hwbridge.viz.foxglove import start_viz

    with open_graph(ctx) as graph:
        server = start_viz(graph, host=host, port=port, topics=topic)
        try:
            sys.stdout.write(server.url + "\n")
            sys.stdout.flush()
            sys.stderr.write(
                f"hwbridge: serving the graph to Foxglove on {server.url}; Ctrl-C stops\n"
            )
            sys.stderr.flush()
            wait_for_signal()
        finally:
            server.close()
