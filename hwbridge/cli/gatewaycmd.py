"""``hwbridge ros2`` and ``hwbridge ros1``: gateways from the hwbridge graph into ROS graphs."""

from __future__ import annotations

import os
import sys
from typing import TYPE_CHECKING, Annotated

import typer

from hwbridge.cli.common import open_graph
from hwbridge.cli.stopping import STOP
from hwbridge.errors import HwBridgeError

if TYPE_CHECKING:
    from hwbridge.gateway.ros2_interfaces import Ros2Interfaces

__all__ = ["QOS_HELP", "qos_rules", "ros1", "ros2"]

_REEXEC_GUARD = "HWBRIDGE_ROS2_ENV"

TopicOption = Annotated[
    list[str] | None,
    typer.Option(
        "--topic",
        "-t",
        metavar="PATTERN",
        help="Mirror topics matching PATTERN (shell pattern, e.g. '/diffbot/*'); repeatable; "
        "default all.",
    ),
]
ExcludeOption = Annotated[
    list[str] | None,
    typer.Option(
        "--exclude", "-x", metavar="PATTERN", help="Do not mirror matching names; repeatable."
    ),
]
ServiceOption = Annotated[
    list[str] | None,
    typer.Option(
        "--service",
        "-s",
        metavar="PATTERN",
        help="Serve matching graph services in ROS; repeatable; default all.",
    ),
]
RosServiceOption = Annotated[
    list[str] | None,
    typer.Option(
        "--ros-service",
        metavar="PATTERN",
        help="Serve matching ROS services on the graph; repeatable; default none.",
    ),
]
NodeOption = Annotated[
    str, typer.Option("--node-name", help="Name of the gateway's node in ROS and on the graph.")
]


def _reexec(env: dict[str, str]) -> None:
    """Start this command again in ``env``, unless a stop signal came already. SIGINT and
    SIGTERM stay blocked across the exec, so one that comes meanwhile is not lost to the new
    interpreter's default handling: hwbridge's first import unblocks them, to its handler."""
    import signal

    signals = (signal.SIGINT, signal.SIGTERM)
    signal.pthread_sigmask(signal.SIG_BLOCK, signals)
    try:
        if not STOP.is_set():  # else main() ends the process
            os.execve(sys.executable, sys.orig_argv, env)
    finally:  # stopped, or the exec failed
        signal.pthread_sigmask(signal.SIG_UNBLOCK, signals)


def _say(text: str) -> None:
    sys.stderr.write(text + "\n")
    sys.stderr.flush()


def qos_rules(values: list[str] | None, option: str = "--qos") -> list[tuple[str, str]]:
    """``PATTERN=KIND`` options as (pattern, kind) rules, in order; a usage error (exit 2)
    for a bad one."""
    from hwbridge.gateway.qos import parse_rule

    rules: list[tuple[str, str]] = []
    for value in values or []:
        try:
            rules.append(parse_rule(value))
        except ValueError as exc:
            raise typer.BadParameter(str(exc), param_hint=option) from exc
    return rules


QOS_HELP = (
    "ROS 2 QoS for topics matching PATTERN (shell pattern, e.g. '/diffbot/*'); repeatable, "
    "the first matching pattern wins. KIND: reliable (reaches default and sensor-data "
    "subscribers), sensor (best effort: sensor-data subscribers only), tf (reliable, keep "
    "last 100), latched (reliable, transient local). Default: what the gateway publishes "
    "reliable (/tf: tf, /tf_static: latched); its subscriptions best effort, taking reliable "
    "and best-effort publishers alike."
)


def _interfaces() -> Ros2Interfaces:
    """tf2_msgs for the gateway: built at first use; without it (no compiler) the gateway
    runs on and says that /tf is not mirrored."""
    import importlib.util

    from hwbridge.gateway.ros2_interfaces import Ros2Interfaces, ensure_interfaces

    if importlib.util.find_spec("rclpy") is None:
        return Ros2Interfaces(None, ())  # load_rclpy says what to install
    try:
        return ensure_interfaces(_say)
    except HwBridgeError as exc:
        _say(f"hwbridge ros2: /tf and /tf_static will not reach ROS 2: {exc}")
        return Ros2Interfaces(None, ())


def _print_interfaces() -> None:
    from hwbridge.gateway.ros2_interfaces import ensure_interfaces

    built = ensure_interfaces(_say)
    if built.setup_script is None:
        _say("hwbridge ros2: tf2_msgs comes from your ROS 2 installation: nothing to build")
        sys.stdout.write(f"{os.devnull}\n")  # still something to source
        return
    _say(f"hwbridge ros2: {', '.join(built.packages)} in {built.prefix}; for other ROS 2 nodes:")
    _say(f'  source "{built.setup_script}"')
    sys.stdout.write(f"{built.setup_script}\n")


def ros2(
    ctx: typer.Context,
    topic: TopicOption = None,
    exclude: ExcludeOption = None,
    service: ServiceOption = None,
    ros_service: RosServiceOption = None,
    qos: Annotated[
        list[str] | None,
        typer.Option("--qos", metavar="PATTERN=KIND", help=QOS_HELP),
    ] = None,
    node_name: NodeOption = "hwbridge_gateway",
    no_rosout: Annotated[
        bool, typer.Option("--no-rosout", help="Do not forward board logs to /rosout.")
    ] = False,
    interfaces: Annotated[
        bool,
        typer.Option(
            "--interfaces",
            help="Build the message packages the ROS 2 wheels lack (tf2_msgs, for /tf) if they "
            "are not built yet, print the setup.sh that puts them on your paths (/dev/null "
            "when a sourced ROS 2 installation has them), and exit.",
        ),
    ] = False,
) -> None:
    """Mirror the graph's topics and services into ROS 2 (rclpy) until Ctrl-C.

    The ROS 2 graph is the one ROS_DOMAIN_ID selects; rclpy comes with hwbridge's ros2 extra.
    Topics go into ROS 2 reliable, so that default-QoS subscribers (Nav2, RViz, a plain
    create_subscription(T, topic, cb, 10)) and sensor-data ones both receive them; --qos
    changes that per topic.
    """
    from hwbridge.gateway.common import Selection
    from hwbridge.gateway.qos import QosRules
    from hwbridge.gateway.ros2 import (
        Ros2Options,
        environment_ready,
        load_rclpy,
        ros2_environment,
        run_ros2_gateway,
    )
    from hwbridge.gateway.ros2_interfaces import environment_has, interfaces_environment

    rules = QosRules.of(qos_rules(qos))
    if interfaces:
        _print_interfaces()
        return
    if not os.environ.get(_REEXEC_GUARD):
        extra = _interfaces()  # tf2_msgs, built at first use
        if not environment_ready() or not environment_has(extra):
            # rclpy's libraries are found through LD_LIBRARY_PATH, read when the process
            # starts: start again with it set (once).
            env = interfaces_environment(extra, ros2_environment())
            env[_REEXEC_GUARD] = "1"
            sys.stdout.flush()
            sys.stderr.flush()
            _reexec(env)
            if STOP.is_set():
                return
    load_rclpy()
    options = Ros2Options(
        topics=Selection.of(topic, exclude),
        services=Selection.of(service, exclude),
        ros_services=Selection(tuple(ros_service or ()), tuple(exclude or ())),
        node_name=node_name,
        qos=rules,
        rosout=not no_rosout,
    )
    try:
        run_ros2_gateway(lambda: open_graph(ctx), options, STOP, announce=_say)
    except HwBridgeError:
        raise
    except Exception as exc:
        raise HwBridgeError(f"ROS 2 gateway failed: {exc}") from exc


def ros1(
    ctx: typer.Context,
    topic: TopicOption = None,
    exclude: ExcludeOption = None,
    service: ServiceOption = None,
    ros_service: RosServiceOption = None,
    param: Annotated[
        list[str] | None,
        typer.Option(
            "--param",
            metavar="NAMESPACE",
            help="Copy the ROS parameter server's parameters under NAMESPACE to the graph's "
            "(and so to boards), and follow their changes; repeatable.",
        ),
    ] = None,
    master: Annotated[
        str | None,
        typer.Option(
            "--master",
            envvar="ROS_MASTER_URI",
            help="ROS master URI (default http://127.0.0.1:11311).",
        ),
    ] = None,
    node_name: NodeOption = "hwbridge_gateway",
    no_rosout: Annotated[
        bool, typer.Option("--no-rosout", help="Do not forward board logs to /rosout.")
    ] = False,
) -> None:
    """Mirror the graph's topics and services into a ROS 1 master's graph until Ctrl-C."""
    from hwbridge.gateway.common import Selection
    from hwbridge.gateway.ros1 import Ros1Options, run_ros1_gateway

    options = Ros1Options(
        master_uri=master or "http://127.0.0.1:11311",
        topics=Selection.of(topic, exclude),
        services=Selection.of(service, exclude),
        ros_services=Selection(tuple(ros_service or ()), tuple(exclude or ())),
        params=tuple(param or ()),
        node_name=node_name,
        rosout=not no_rosout,
    )
    run_ros1_gateway(lambda: open_graph(ctx), options, STOP, announce=_say)
