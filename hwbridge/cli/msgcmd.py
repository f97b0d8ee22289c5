"""``hwbridge msg`` and ``hwbridge srv``: inspect message and service types."""

from __future__ import annotations

from typing import Annotated

import typer

from hwbridge import msg
from hwbridge.cli.common import get_registry
from hwbridge.errors import UnknownTypeError

__all__ = ["msg_app", "srv_app"]

msg_app = typer.Typer(help="Message types: list, show, md5.", no_args_is_help=True)
srv_app = typer.Typer(help="Service types: list, show, md5.", no_args_is_help=True)

TypeArg = Annotated[
    str, typer.Argument(metavar="TYPE", help="ROS 1 type name, e.g. sensor_msgs/Imu")
]
SrvArg = Annotated[str, typer.Argument(metavar="TYPE", help="Service type, e.g. std_srvs/Trigger")]
PackageArg = Annotated[
    str | None, typer.Argument(metavar="[PKG]", help="Only types of this package.")
]


def _check_package(reg: msg.TypeRegistry, package: str | None, names: list[str]) -> None:
    if package is not None and not names:
        from hwbridge.protocols.msgtypes import suggest

        raise UnknownTypeError(
            package, suggest(package, reg.packages()), "package", reg.search_path
        )


@msg_app.command("list")
def msg_list(ctx: typer.Context, package: PackageArg = None) -> None:
    """List message types, one per line."""
    reg = get_registry(ctx)
    names = reg.message_names(package)
    _check_package(reg, package, names)
    typer.echo("\n".join(names))


@msg_app.command("show")
def msg_show(ctx: typer.Context, type_name: TypeArg) -> None:
    """Print a message definition with its nested fields, as rosmsg show does."""
    typer.echo(msg.show(type_name, get_registry(ctx)))


@msg_app.command("md5")
def msg_md5(ctx: typer.Context, type_name: TypeArg) -> None:
    """Print the ROS 1 md5 sum of a message type."""
    typer.echo(get_registry(ctx).message(type_name).md5)


@srv_app.command("list")
def srv_list(ctx: typer.Context, package: PackageArg = None) -> None:
    """List service types, one per line."""
    reg = get_registry(ctx)
    names = reg.service_names(package)
    _check_package(reg, package, names)
    typer.echo("\n".join(names))


@srv_app.command("show")
def srv_show(ctx: typer.Context, type_name: SrvArg) -> None:
    """Print a service definition: request, ``---``, response."""
    reg = get_registry(ctx)
    service = reg.service(type_name)
    request = msg.show(service.request.name, reg)
    response = msg.show(service.response.name, reg)
    typer.echo("\n".join(part for part in (request, "---", response) if part))


@srv_app.command("md5")
def srv_md5(ctx: typer.Context, type_name: SrvArg) -> None:
    """Print the ROS 1 md5 sum of a service type (request text followed by response text)."""
    typer.echo(get_registry(ctx).service(type_name).md5)
