"""The ``hwbridge`` command line.

Exit status: 0 on success, 2 on a usage error (bad option, missing argument, an input path that
does not exist), 1 on any other error; error messages go to stderr (docs/design.md, "Errors and
counters").

Start-up matters (``hwbridge connect`` is timed from launch to a board's first message on the
graph), so importing this package imports typer and nothing else heavy. Each command group lives
in its own module, named in :data:`COMMANDS` with its one-line help and imported only when that
command runs (or its own ``--help`` is asked for); ``hwbridge --help`` lists the table without
importing any of them. The command modules in turn import Zenoh, the message registry (rosbags,
numpy), YAML, serial ports or rich inside the commands that need them.
"""

from __future__ import annotations

import importlib
import logging
import os
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer

from hwbridge._version import __version__
from hwbridge.cli import stopping
from hwbridge.cli.common import Context, show_logs
from hwbridge.cli.shell import ClickException, Command, Group, UsageError, adopt
from hwbridge.errors import HwBridgeError
from hwbridge.heap import keep_the_heap_small

__all__ = ["COMMANDS", "LazyCommand", "build_app", "entry", "main"]


@dataclass(frozen=True)
class LazyCommand:
    """A top-level command: where it lives (``module:attribute``, a Typer group or a command
    function) and the one-line help ``hwbridge --help`` shows for it."""

    target: str
    help: str

    def load(self, name: str) -> Any:
        """The click command, importing its module."""
        module_name, _, attribute = self.target.partition(":")
        obj = getattr(importlib.import_module(module_name), attribute)
        command: Any
        if isinstance(obj, typer.Typer):
            command = typer.main.get_group(adopt(obj))  # a group even with one command
        else:
            single = typer.Typer(add_completion=False)
            single.command(name, cls=Command)(obj)
            command = typer.main.get_command(single)
        command.name = name
        return command


_CLI = "hwbridge.cli."
COMMANDS: dict[str, LazyCommand] = {
    "msg": LazyCommand(_CLI + "msgcmd:msg_app", "Message types: list, show, md5."),
    "srv": LazyCommand(_CLI + "msgcmd:srv_app", "Service types: list, show, md5."),
    "topic": LazyCommand(
        _CLI + "graphcmd:topic_app", "Topics: list, echo, pub, hz, bw, info, type."
    ),
    "service": LazyCommand(_CLI + "graphcmd:service_app", "Services: list, call, type."),
    "param": LazyCommand(
        _CLI + "graphcmd:param_app", "Parameters: list, get, set, delete, load, dump."
    ),
    "node": LazyCommand(_CLI + "graphcmd:node_app", "Nodes: list."),
    "connect": LazyCommand(
        _CLI + "bridgecmd:connect",
        "Connect boards to the graph and keep them connected until Ctrl-C.",
    ),
    "up": LazyCommand(
        _CLI + "upcmd:up",
        "Bring a robot up: its boards and every host node its devices need, until Ctrl-C.",
    ),
    "graph": LazyCommand(
        _CLI + "routercmd:run_graph",
        "Run a graph with no boards until Ctrl-C, for play, record, viz and the topic tools.",
    ),
    "robot": LazyCommand(_CLI + "robotcmd:robot_app", "Robot files: check, show, devices, acl."),
    "board": LazyCommand(
        _CLI + "bridgecmd:board_app",
        "Boards: scan the serial ports; list, info, stats of the running bridge's.",
    ),
    "record": LazyCommand(
        _CLI + "recordcmd:record",
        "Record topics to an MCAP file (ROS 1 profile) until Ctrl-C, --duration or --limit.",
    ),
    "play": LazyCommand(
        _CLI + "recordcmd:play",
        "Publish the messages of an MCAP file with their recorded timing (scaled by --rate).",
    ),
    "emulate": LazyCommand(
        _CLI + "emucmd:emulate",
        "Start a virtual board; the first line printed is the URL to connect to. Ctrl-C stops.",
    ),
    "demo": LazyCommand(
        _CLI + "emucmd:demo",
        "Drive an emulated diffbot through the real bridge and show what the graph sees.",
    ),
    "firmware": LazyCommand(
        _CLI + "firmwarecmd:firmware_app",
        "Firmware: build sketches, measure them, generate headers, run them in simavr, "
        "upload them.",
    ),
    "dxl": LazyCommand(
        _CLI + "dxlcmd:dxl_app", "Dynamixel servos on a serial bus: scan, ping, read, write."
    ),
    "viz": LazyCommand(
        _CLI + "vizcmd:viz",
        "Serve the graph to Foxglove or Lichtblick over WebSocket until Ctrl-C.",
    ),
    "monitor": LazyCommand(
        _CLI + "monitorcmd:monitor",
        "A live terminal view of the running bridge: boards, link state, topics, rates, logs.",
    ),
    "ros2": LazyCommand(
        _CLI + "gatewaycmd:ros2",
        "Mirror the graph's topics and services into ROS 2 (rclpy) until Ctrl-C.",
    ),
    "ros1": LazyCommand(
        _CLI + "gatewaycmd:ros1",
        "Mirror the graph's topics and services into a ROS 1 master's graph until Ctrl-C.",
    ),
}
"""Top-level commands in the order ``hwbridge --help`` lists them."""


class _LazyGroup(Group):
    """The root group: commands from :data:`COMMANDS`, each imported when first resolved.

    While the root's own help is written, commands not yet imported are listed from the
    table (name and one-line help) instead of being imported just to be listed.
    """

    _listing = False

    def list_commands(self, ctx: Any) -> list[str]:
        return [*COMMANDS, *(name for name in super().list_commands(ctx) if name not in COMMANDS)]

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        command = super().get_command(ctx, cmd_name)
        if command is not None:
            return command
        lazy = COMMANDS.get(cmd_name)
        if lazy is None:
            return None
        if self._listing:
            return Command(name=cmd_name, help=lazy.help)
        command = lazy.load(cmd_name)
        self.add_command(command, cmd_name)
        return command

    def format_help(self, ctx: Any, formatter: Any) -> None:
        self._listing = True
        try:
            super().format_help(ctx, formatter)
        finally:
            self._listing = False


def _version(value: bool) -> None:
    if value:
        typer.echo(f"hwbridge {__version__}")
        raise typer.Exit


def build_app() -> typer.Typer:
    """The root Typer application; its commands (:data:`COMMANDS`) load when resolved."""
    app = typer.Typer(
        name="hwbridge",
        cls=_LazyGroup,
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
                exists=True,
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
        show_logs(level)
        ctx.obj = Context(
            msg_path=tuple(msg_path or ()),
            endpoint=endpoint,
            domain=domain,
            zenoh_config=zenoh_config,
        )

    return app


def _error(text: str) -> None:
    """``error: text`` on stderr (``error:`` in bold red on a terminal, unless NO_COLOR)."""
    color = sys.stderr.isatty() and not os.environ.get("NO_COLOR")
    label = "\x1b[1;31merror:\x1b[0m" if color else "error:"
    for line in text.splitlines() or [""]:  # several problems: one error line each
        sys.stderr.write(f"{label} {line}\n")
    sys.stderr.flush()


def _usage_error(exc: UsageError) -> int:
    """``error: ...``, then the usage line and where help is; exit status 2."""
    if type(exc).__name__ == "NoArgsIsHelpError":  # a group run bare: its help, as Click does
        sys.stderr.write(exc.format_message())
        return exc.exit_code
    _error(exc.format_message())
    ctx = exc.ctx
    if ctx is not None:
        sys.stderr.write(ctx.get_usage() + "\n")
        if ctx.command.get_help_option(ctx) is not None:
            sys.stderr.write(f"Try '{ctx.command_path} {ctx.help_option_names[0]}' for help.\n")
    sys.stderr.flush()
    return exc.exit_code


def main(argv: list[str] | None = None) -> int:
    """Console-script entry point; returns the exit status.

    In the main thread it takes SIGINT and SIGTERM over for the run (see
    :mod:`hwbridge.cli.stopping`); after one, it does not return: the process ends with the
    status once stdout and stderr are flushed."""
    restore: Callable[[], None] | None = None
    keep_the_heap_small()  # before any thread allocates: see hwbridge.heap
    try:
        restore = stopping.install()
        code = _run(argv)
    except KeyboardInterrupt:  # outside _run's handlers
        code = _interrupted()
    signum = stopping.signalled()
    if signum is not None and threading.current_thread() is threading.main_thread():
        if code == 130 or (code == 1 and stopping.STOP.is_set()):
            code = 128 + signum  # 130 for SIGINT, 143 for SIGTERM
        stopping.exit_now(code)
    if restore is not None:
        restore()
    return code


def entry() -> NoReturn:
    """The ``hwbridge`` process (console script and ``python -m hwbridge``): :func:`main`,
    then the process ends through :func:`hwbridge.cli.stopping.leave`, without the
    interpreter's finalization. In-process callers (tests) call :func:`main` and go on."""
    stopping.leave(main())


def _interrupted() -> int:
    sys.stderr.write("interrupted\n")
    sys.stderr.flush()
    return 130


def _run(argv: list[str] | None) -> int:
    app = build_app()
    try:
        result = app(args=argv, prog_name="hwbridge", standalone_mode=False)
    except SystemExit as exc:
        code = exc.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    except UsageError as exc:
        return _usage_error(exc)
    except ClickException as exc:  # a file option that cannot be opened...
        _error(exc.format_message())
        return exc.exit_code
    except HwBridgeError as exc:
        _error(str(exc))
        return 1
    except OSError as exc:  # a file to write where none can be: no such folder, a full disk...
        _error(f"{exc.filename}: {exc.strerror}" if exc.filename and exc.strerror else str(exc))
        return 1
    except typer.Abort as exc:  # Click turns a KeyboardInterrupt into Abort
        if isinstance(exc.__context__, KeyboardInterrupt) or stopping.STOP.is_set():
            return _interrupted()
        _error("aborted")
        return 1
    except KeyboardInterrupt:
        return _interrupted()
    # Without standalone mode, typer.Exit(code) comes back as its code; a command's own return
    # value (None) means success. Typer turns a KeyboardInterrupt (start-up cut short by a
    # signal) into Exit(130), which comes back here as 130 with nothing said.
    if result == 130 and stopping.signalled() is not None:
        return _interrupted()
    return result if isinstance(result, int) else 0


if __name__ == "__main__":
    sys.exit(main())
