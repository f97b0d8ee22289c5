"""``hwbridge graph``: the graph alone, with no boards.

The same Zenoh router ``connect`` and ``up`` start (on the same endpoint, domain and Zenoh
config), and the parameter server a bridge holds, so that ``play``, ``record``, ``viz`` and the
``topic``, ``service`` and ``param`` tools have something to attach to on a machine without a
board.
"""

from __future__ import annotations

import sys

import typer

from hwbridge.cli.bridgecmd import ListenOption, ParamsOption, owner_config, read_params
from hwbridge.cli.bridgecmd import wait_for_signal as wait_for_stop

__all__ = ["run_graph"]


def run_graph(ctx: typer.Context, params: ParamsOption = None, listen: ListenOption = None) -> None:
    """Run a graph with no boards until Ctrl-C, for play, record, viz and the topic tools.

    The first line printed (on stdout) is the endpoint tools attach to; then play, record, viz,
    topic, service and param work against it as against a bridge's graph.
    """
    from hwbridge.graph import Graph, ParamServer

    initial = read_params(params)
    config = owner_config(ctx, listen)
    graph = Graph(config)
    try:
        ParamServer(graph, initial)
        endpoints = ", ".join(config.listen) or f"the endpoints of {config.config_file}"
        sys.stdout.write(f"{endpoints}\n")
        sys.stdout.flush()
        sys.stderr.write(f"hwbridge: graph on {config.describe()}, no boards; Ctrl-C stops\n")
        sys.stderr.flush()
        wait_for_stop()
    finally:
        graph.close()
