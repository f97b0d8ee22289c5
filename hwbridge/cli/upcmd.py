"""``hwbridge up ROBOT.yaml``: a whole robot from its robot file."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from hwbridge.cli.bridgecmd import (
    ListenOption,
    ParamsOption,
    owner_config,
    read_params,
    wait_for_signal,
)
from hwbridge.cli.common import get_registry

__all__ = ["up"]


def _links(values: list[str] | None) -> dict[str, str]:
    links: dict[str, str] = {}
    for value in values or []:
        name, sep, url = value.partition("=")
        if not sep or not name or not url:
            raise typer.BadParameter(
                f"{value!r}: write NAME=URL, e.g. base=socket://127.0.0.1:2323", param_hint="--link"
            )
        links[name] = url
    return links


def up(
    ctx: typer.Context,
    robot_file: Annotated[
        Path, typer.Argument(metavar="ROBOT.yaml", help="The robot file (see 'hwbridge robot').")
    ],
    link: Annotated[
        list[str] | None,
        typer.Option(
            "--link",
            "-l",
            metavar="NAME=URL",
            help="Use URL for the board (or host device) NAME instead of the file's link; "
            "repeatable.",
        ),
    ] = None,
    wait: Annotated[
        bool,
        typer.Option("--wait", help="Keep waiting for boards whose link does not open yet."),
    ] = False,
    params: ParamsOption = None,
    listen: ListenOption = None,
) -> None:
    """Bring a robot up: its boards and every host node its devices need, until Ctrl-C."""
    from hwbridge.graph import Graph
    from hwbridge.robot.config import load_robot
    from hwbridge.robot.runtime import RobotRuntime

    overrides = _links(link)
    robot = load_robot(robot_file).with_links(overrides)
    initial = read_params(params)
    config = owner_config(ctx, listen)
    graph = Graph(config)
    try:
        graph.registry = get_registry(ctx)
        runtime = RobotRuntime(robot, graph, params=initial, wait_for_boards=wait)
        runtime.start()
        try:
            sys.stderr.write(
                f"hwbridge: robot {robot.name} up on {config.describe()}; Ctrl-C stops\n"
                f"{runtime.summary()}\n"
            )
            sys.stderr.flush()
            wait_for_signal()
        finally:
            runtime.stop()
    finally:
        graph.close()
