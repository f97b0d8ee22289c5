"""``hwbridge robot``: check a robot file, show it as hwbridge reads it, list device types."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

import typer

from hwbridge.cli.aclcmd import acl
from hwbridge.cli.common import RobotFileArg
from hwbridge.cli.upcmd import LinkOption, parse_links, show_notes

if TYPE_CHECKING:
    from hwbridge.robot.model import Robot

__all__ = ["robot_app"]

robot_app = typer.Typer(help="Robot files: check, show, devices, acl.", no_args_is_help=True)


@robot_app.command("check")
def check(robot_file: RobotFileArg, link: LinkOption = None) -> None:
    """Check a robot file: every problem as FILE:LINE: what is wrong (exit status 1).

    With --link, the links 'hwbridge up --link' would use, checked and noted as 'up' does."""
    from hwbridge.robot.config import check_robot

    robot, notes = check_robot(robot_file, parse_links(link))  # what 'hwbridge up' runs too
    show_notes(notes)
    boards = ", ".join(f"{b.name}: {_count(len(b.devices), 'device')}" for b in robot.boards)
    sys.stdout.write(
        f"{robot_file}: robot {robot.name}: {_count(len(robot.boards), 'board')}"
        f"{f' ({boards})' if boards else ''}, "
        f"{_count(len(robot.host_devices), 'host device')}"
        f"{_gateways(robot)}\n"
    )


def _gateways(robot: Robot) -> str:
    """What the robot file's ``ros:`` section has ``hwbridge up`` start, for ``robot check``."""
    names = [name for name, on in (("ROS 2", robot.ros2), ("ROS 1", robot.ros1)) if on]
    qos = ", ".join(f"{pattern}={kind}" for pattern, kind in robot.ros2_qos)
    return (
        f"; 'up' starts the {' and '.join(names)} gateway{'s' if len(names) > 1 else ''}"
        if names
        else ""
    ) + (f"; ROS 2 QoS {qos}" if qos else "")


def _count(number: int, what: str) -> str:
    return f"{number} {what}{'' if number == 1 else 's'}"


@robot_app.command("show")
def show(robot_file: RobotFileArg) -> None:
    """Print a robot file as hwbridge reads it (YAML, every default filled in; a file that
    hwbridge reads back as the same robot)."""
    import yaml

    from hwbridge.robot.config import load_robot

    robot = load_robot(robot_file)

    def device(d: Any) -> dict[str, Any]:
        return {"type": d.type, "name": d.name, **dict(d.settings)}

    data: dict[str, Any] = {
        "robot": robot.name,
        "boards": [
            {
                "name": b.name,
                "link": b.link,
                "protocol": b.protocol,
                "namespace": b.namespace,
                **({"baud": b.baud} if b.baud is not None else {}),
                "service_timeout": b.service_timeout,
                "start_delay": b.start_delay,
                "devices": [device(d) for d in b.devices],
            }
            for b in robot.boards
        ],
        "host_devices": [
            {
                **device(h.device),
                "link": h.link,
                "namespace": h.namespace,
                **({"baud": h.baud} if h.baud is not None else {}),
            }
            for h in robot.host_devices
        ],
    }
    if robot.world:
        data["world"] = dict(robot.world)
    if robot.ros2 or robot.ros1 or robot.ros2_qos:
        ros: dict[str, Any] = {"ros2": robot.ros2, "ros1": robot.ros1}
        if robot.ros2_qos:
            ros["qos"] = dict(robot.ros2_qos)
        data["ros"] = ros
    if robot.boards_per_process is not None:
        data["boards_per_process"] = robot.boards_per_process
    sys.stdout.write(yaml.safe_dump(data, sort_keys=False))


@robot_app.command("devices")
def devices() -> None:
    """List the device types robot files can use, with their settings."""
    from hwbridge.errors import HwBridgeError
    from hwbridge.robot.plugin import REQUIRED
    from hwbridge.robot.registry import device_types, get_device

    for name in device_types():
        try:
            plugin = get_device(name)
        except HwBridgeError as exc:
            sys.stdout.write(f"{name}: cannot be loaded: {exc}\n")
            continue
        except Exception as exc:  # noqa: BLE001 - a plugin that fails to import
            sys.stdout.write(f"{name}: cannot be loaded: {type(exc).__name__}: {exc}\n")
            continue
        sys.stdout.write(f"{name} ({plugin.where}): {plugin.summary}\n")
        sys.stdout.write(f"  firmware driver: {plugin.firmware or 'none'}\n")
        for field in plugin.fields:
            default = "required" if field.default is REQUIRED else f"default {field.default!r}"
            doc = f": {field.doc}" if field.doc else ""
            sys.stdout.write(f"    {field.name} ({default}){doc}\n")


robot_app.command("acl")(acl)
