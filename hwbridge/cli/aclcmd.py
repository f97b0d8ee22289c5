"""``hwbridge robot acl ROBOT.yaml``: a Zenoh router config that lets viewers read the running
robot's topics but not drive it (see :mod:`hwbridge.graph.acl` and docs/graph.md)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from hwbridge.cli.common import RobotFileArg, open_graph
from hwbridge.errors import HwBridgeError

__all__ = ["acl"]


def acl(
    ctx: typer.Context,
    robot_file: RobotFileArg,
    output: Annotated[
        Path | None,
        typer.Option("--output", "-o", help="Write the config here (default: standard output)."),
    ] = None,
    users: Annotated[
        str,
        typer.Option(
            "--users",
            metavar="FILE",
            help="The logins file the router reads (one name:password per line).",
        ),
    ] = "users.txt",
    listen: Annotated[
        list[str] | None,
        typer.Option("--listen", metavar="ENDPOINT", help="Endpoint to listen on; repeatable."),
    ] = None,
    viewer: Annotated[
        list[str] | None,
        typer.Option("--viewer", metavar="USER", help="A read-only user; repeatable."),
    ] = None,
    operator: Annotated[
        list[str] | None,
        typer.Option("--operator", metavar="USER", help="A user with full access; repeatable."),
    ] = None,
    timeout: Annotated[
        float, typer.Option("--timeout", help="Seconds to wait for the graph's discovery.")
    ] = 2.0,
) -> None:
    """Write a Zenoh router config with access control for a running robot: viewers may
    subscribe to its topics, only operators may publish to what it subscribes or call its
    services. Start the robot first ('hwbridge up ROBOT.yaml'), then restart it with
    'hwbridge --zenoh-config FILE up ROBOT.yaml'."""
    from hwbridge.graph.acl import router_config, surface_of
    from hwbridge.robot.config import load_robot

    robot = load_robot(robot_file)
    namespaces = [b.namespace for b in robot.boards] + [h.namespace for h in robot.host_devices]
    with open_graph(ctx) as graph:
        snapshot = graph.snapshot(timeout=timeout, settle=min(0.5, timeout))
        surface = surface_of(snapshot, namespaces or ["/"], exclude_sessions=[graph.zid])
        prefix = graph.prefix
        where = graph.config.describe()
    if surface.empty:
        raise HwBridgeError(
            f"robot {robot.name}: no topics or services under "
            f"{', '.join(sorted(set(namespaces))) or '/'} on the graph ({where}); "
            f"bring the robot up first: hwbridge up {robot_file}"
        )
    text = router_config(
        surface,
        robot=robot.name,
        prefix=prefix,
        listen=listen or ["tcp/0.0.0.0:7447"],
        users_file=users,
        viewers=viewer if viewer is not None else ["viewer"],
        operators=operator if operator is not None else ["operator"],
    )
    if output is None:
        sys.stdout.write(text)
    else:
        output.write_text(text, encoding="utf-8")
        sys.stderr.write(
            f"{output}: {len(surface.readable)} readable topics, "
            f"{len(surface.commands)} command topics and {len(surface.services)} services "
            f"of robot {robot.name}\n"
        )
