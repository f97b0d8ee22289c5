"""The ``hwbridge`` command line.

Exit status: 0 on success, 2 on a usage error (bad option, missing argument), 1 on any other
error; error messages go to stderr. Each command group lives in its own module and is added in
:func:`build_app`; heavy imports (Zenoh, serial ports) happen inside the commands that need them.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from hwbridge._version import __version__
from hwbridge.cli import bridgecmd, dxlcmd, emucmd, graphcmd, msgcmd, recordcmd
from hwbridge.cli.common import Context, console_err
from hwbridge.errors import HwBridgeError

__all__ = ["build_app", "main"]


def _version(value: bool) -> None:
    if value:
        typer.echo(f"hwbridge {__version__}")
        raise typer.Exit


def build_app() -> typer.Typer:
    """The root Typer application with every command group attached."""
    app = typer.Typer(
        name="hwbridge",
        help="Connect microcontroller boards to a host graph of topics and services.",
        no_args_is_help=True,
        pretty_exceptions_enable=False,
        context_settings={"help_option_names": ["-h", "--help"]},
        add_completion=False,
    )

    @app.callback()
    def root(
        ctx: typer.Context,
        msg_path: Annotated[
            list[Path] | None,
            typer.Option(
                "--msg-path",
                help="Directory of message packages (PKG/msg/*.msg, PKG/srv/*.srv); repeatable. "
                "Searched before HWBRIDGE_MSG_PATH.",
                file_okay=False,
            ),
        ] = None,
        endpoint: Annotated[
            str | None,
            typer.Option(
                "--endpoint",
                envvar="HWBRIDGE_ENDPOINT",
                help="Zenoh endpoint of the running bridge (default tcp/127.0.0.1:7447).",
            ),
        ] = None,
        domain: Annotated[
            str | None,
            typer.Option("--domain", envvar="HWBRIDGE_DOMAIN", help="Graph domain (default 0)."),
        ] = None,
        zenoh_config: Annotated[
            Path | None,
            typer.Option(
                "--zenoh-config",
                envvar="HWBRIDGE_ZENOH_CONFIG",
                dir_okay=False,
                exists=True,
                help="Zenoh JSON5 config (TLS, user/password, access control); see docs/graph.md.",
            ),
        ] = None,
        verbose: Annotated[
            int, typer.Option("--verbose", "-v", count=True, help="More log output (-vv: debug).")
        ] = 0,
        version: Annotated[
            bool,
            typer.Option(
                "--version", callback=_version, is_eager=True, help="Print the version and exit."
            ),
        ] = False,
    ) -> None:
        level = logging.WARNING - 10 * min(verbose, 2)
        logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
        ctx.obj = Context(
            msg_path=tuple(msg_path or ()),
            endpoint=endpoint,
            domain=domain,
            zenoh_config=zenoh_config,
        )

    app.add_typer(msgcmd.msg_app, name="msg")
    app.add_typer(msgcmd.srv_app, name="srv")
    app.add_typer(graphcmd.topic_app, name="topic")
    app.add_typer(graphcmd.service_app, name="service")
    app.add_typer(graphcmd.param_app, name="param")
    app.add_typer(graphcmd.node_app, name="node")
    app.command("connect")(bridgecmd.connect)
    app.add_typer(bridgecmd.board_app, name="board")
    app.command("record")(recordcmd.record)
    app.command("play")(recordcmd.play)
    app.command("emulate")(emucmd.emulate)
    app.command("demo")(emucmd.demo)
    app.add_typer(dxlcmd.dxl_app, name="dxl")
    return app


def main(argv: list[str] | None = None) -> int:
    """Console-script entry point; returns the exit status."""
    app = build_app()
    try:
        app(args=argv, prog_name="hwbridge", standalone_mode=True)
    except SystemExit as exc:
        code = exc.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    except HwBridgeError as exc:
        console_err.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False)
        return 1
    except KeyboardInterrupt:
        console_err.print("interrupted")
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
