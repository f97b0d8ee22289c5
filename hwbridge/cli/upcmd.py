"""``hwbridge up ROBOT.yaml``: a whole robot from its robot file."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Annotated

import typer

from hwbridge.cli.bridgecmd import (
    ListenOption,
    ParamsOption,
    QuietOption,
    owner_config,
    read_params,
    show_board_logs,
    wait_for_signal,
)
from hwbridge.cli.common import RobotFileArg, get_registry
from hwbridge.cli.gatewaycmd import QOS_HELP, qos_rules
from hwbridge.robot.shards import DEFAULT_BOARDS_PER_PROCESS, Shards, fail_with, plan_shards

if TYPE_CHECKING:
    from hwbridge.gateway.launch import GatewayProcess
    from hwbridge.graph import GraphConfig
    from hwbridge.robot.model import Robot
    from hwbridge.robot.runtime import RobotRuntime
    from hwbridge.viz.foxglove import VizServer

__all__ = ["LinkOption", "parse_links", "show_notes", "up"]

LinkOption = Annotated[
    list[str] | None,
    typer.Option(
        "--link",
        "-l",
        metavar="NAME=URL",
        help="Use URL for the board (or host device) NAME instead of the file's link; repeatable.",
    ),
]


def show_notes(notes: list[str]) -> None:
    """``note: FILE:LINE: ...`` lines on stderr (what was taken differently from the file)."""
    for note in notes:
        sys.stderr.write(f"note: {note}\n")
    sys.stderr.flush()


def parse_links(values: list[str] | None) -> dict[str, str]:
    """The ``--link NAME=URL`` values by name; a usage error for one without ``=``."""
    links: dict[str, str] = {}
    for value in values or []:
        name, sep, url = value.partition("=")
        if not sep or not name or not url:
            raise typer.BadParameter(
                f"{value!r}: write NAME=URL, e.g. base=socket://127.0.0.1:2323", param_hint="--link"
            )
        links[name] = url
    return links


def _start_gateways(
    ctx: typer.Context,
    config: GraphConfig,
    robot: Robot,
    *,
    ros2: bool | None,
    ros1: bool | None,
    ros2_qos: Sequence[tuple[str, str]] = (),
) -> list[GatewayProcess]:
    """The gateway processes asked for, attached to this robot's graph: by ``--ros2``/``--ros1``
    (``--no-...``: not), else by the robot file's ``ros:`` section. The ROS 2 gateway gets the
    QoS rules of ``--ros2-qos`` first, then the file's (the first match wins)."""
    from hwbridge.gateway.launch import GatewayProcess
    from hwbridge.gateway.qos import QosRules

    msg_path = [str(p) for p in getattr(ctx.find_root().obj, "msg_path", ())]
    started: list[GatewayProcess] = []
    for kind, flag, in_file in (("ros2", ros2, robot.ros2), ("ros1", ros1, robot.ros1)):
        if not (in_file if flag is None else flag):
            continue
        why = f"--{kind}" if flag is not None else f"the robot file's 'ros: {{{kind}: true}}'"
        sys.stderr.write(f"hwbridge: starting 'hwbridge {kind}' ({why})\n")
        sys.stderr.flush()
        extra: list[str] = []
        if kind == "ros1":
            namespaces = sorted({b.namespace for b in robot.boards if b.namespace != "/"})
            extra = [arg for ns in namespaces for arg in ("--param", ns)]
        else:
            extra = list(QosRules.of(ros2_qos, robot.ros2_qos).as_args("--qos"))
        started.append(GatewayProcess(kind, config, extra, msg_path=msg_path))
    return started


def up(
    ctx: typer.Context,
    robot_file: RobotFileArg,
    link: LinkOption = None,
    wait: Annotated[
        bool,
        typer.Option("--wait", help="Keep waiting for boards whose link does not open yet."),
    ] = False,
    params: ParamsOption = None,
    listen: ListenOption = None,
    ros2: Annotated[
        bool | None,
        typer.Option(
            "--ros2/--no-ros2",
            help="Also start 'hwbridge ros2': the robot's topics and services in ROS 2. "
            "Default: the robot file's 'ros: {ros2: ...}' (off).",
            show_default=False,
        ),
    ] = None,
    ros1: Annotated[
        bool | None,
        typer.Option(
            "--ros1/--no-ros1",
            help="Also start 'hwbridge ros1' (master from ROS_MASTER_URI): the robot in ROS 1, "
            "its boards' namespaces' parameters from the ROS parameter server. "
            "Default: the robot file's 'ros: {ros1: ...}' (off).",
            show_default=False,
        ),
    ] = None,
    ros2_qos: Annotated[
        list[str] | None,
        typer.Option(
            "--ros2-qos",
            metavar="PATTERN=KIND",
            help=f"{QOS_HELP} Passed to 'hwbridge ros2 --qos', before the robot file's "
            "'ros: {qos: ...}' rules (so these win).",
            show_default=False,
        ),
    ] = None,
    viz: Annotated[
        bool,
        typer.Option(
            "--viz", help="Also serve the graph's topics to Foxglove (see 'hwbridge viz')."
        ),
    ] = False,
    viz_port: Annotated[
        int,
        typer.Option("--viz-port", min=0, max=65535, help="Foxglove WebSocket port (0: any)."),
    ] = 8765,
    boards_per_process: Annotated[
        int | None,
        typer.Option(
            "--boards-per-process",
            min=0,
            help="With more boards than this, run them in several bridge processes of at most "
            "this many boards each (this process keeps the graph, parameters, host devices, "
            "viz and gateways); 0: every board in this process. Default: the robot file's "
            f"'boards_per_process', else {DEFAULT_BOARDS_PER_PROCESS}.",
            show_default=False,
        ),
    ] = None,
    shard: Annotated[str | None, typer.Option("--shard", hidden=True)] = None,
    quiet: QuietOption = False,
) -> None:
    """Bring a robot up: its boards and every host node its devices need, until Ctrl-C.

    The robot file is checked as 'hwbridge robot check' checks it; the boards' log lines (INFO
    and above) show on stderr, --quiet hides the info ones. A robot with more boards than
    --boards-per-process (16) runs them in child bridge processes on the same graph (one
    bridge process slows down past a few dozen boards); nothing else changes for a user, and
    Ctrl-C stops them all. --boards-per-process 0 keeps every board in this process."""
    if shard is not None:
        from hwbridge.cli.shardrun import run_shard

        show_board_logs(quiet)
        run_shard(ctx, robot_file, parse_links(link), shard, wait=wait)
        return
    from hwbridge.graph import Graph
    from hwbridge.robot.config import check_robot
    from hwbridge.robot.runtime import RobotRuntime

    qos = qos_rules(ros2_qos, "--ros2-qos")
    robot, notes = check_robot(robot_file, parse_links(link))  # as 'hwbridge robot check' does
    if qos and not (robot.ros2 if ros2 is None else ros2):
        raise typer.BadParameter(
            "the ROS 2 gateway is not started: add --ros2 (or 'ros: {ros2: true}' in the "
            "robot file)",
            param_hint="--ros2-qos",
        )
    show_notes(notes)
    initial = read_params(params)
    show_board_logs(quiet)
    per_process = boards_per_process
    if per_process is None:
        per_process = robot.boards_per_process
    if per_process is None:
        per_process = DEFAULT_BOARDS_PER_PROCESS
    groups = plan_shards([b.name for b in robot.boards], per_process)
    config = owner_config(ctx, listen)
    shards = Shards(groups) if groups else None
    graph = Graph(shards.parent_config(config) if shards else config)
    try:
        graph.registry = get_registry(ctx)
        runtime = RobotRuntime(
            robot, graph, params=initial, wait_for_boards=wait, run_boards=shards is None
        )
        _up(ctx, robot, config, runtime, shards, quiet=quiet, wait=wait)
        gateways: list[GatewayProcess] = []
        server: VizServer | None = None
        try:
            sys.stderr.write(
                f"hwbridge: robot {robot.name} up on {config.describe()}; Ctrl-C stops\n"
                f"{runtime.summary()}\n" + (f"{shards.describe()}\n" if shards else "")
            )
            if viz:
                from hwbridge.viz.foxglove import start_viz

                server = start_viz(graph, port=viz_port)
                sys.stderr.write(f"hwbridge: Foxglove WebSocket on {server.url}\n")
            sys.stderr.flush()
            gateways = _start_gateways(ctx, config, robot, ros2=ros2, ros1=ros1, ros2_qos=qos)
            _wait(shards)
        finally:
            if shards is not None:
                shards.stop()
            for gateway in reversed(gateways):
                gateway.stop()
            if server is not None:
                server.close()
            runtime.stop()
    finally:
        graph.close()


def _up(
    ctx: typer.Context,
    robot: Robot,
    config: GraphConfig,
    runtime: RobotRuntime,
    shards: Shards | None,
    *,
    quiet: bool,
    wait: bool,
) -> None:
    """Start the runtime, then the shards (if any) with the links the runtime resolved. A
    Ctrl-C meanwhile raises KeyboardInterrupt here, and the shards started are stopped."""
    runtime.start()
    if shards is None:
        return
    links = {b.name: b.link for b in runtime.robot.boards}
    options = [*(["--quiet"] if quiet else []), *(["--wait"] if wait else [])]
    msg_path = [str(p) for p in getattr(ctx.find_root().obj, "msg_path", ())]
    try:
        shards.start(config, msg_path, robot.path, links, options)
    except BaseException:
        runtime.stop()
        raise


def _wait(shards: Shards | None) -> None:
    """Until Ctrl-C (SIGINT or SIGTERM), or until a shard ends (an error naming its boards)."""
    if shards is None:
        wait_for_signal()
        return
    from hwbridge.cli.stopping import STOP, on_signal

    with on_signal(shards.interrupt):
        while not STOP.wait(0.25):
            failed = shards.failed()
            if failed is not None:
                raise fail_with(failed)
