"""Helpers shared by the command modules: the per-invocation context, consoles and output."""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

if TYPE_CHECKING:
    from rich.console import Console

    from hwbridge.graph import Graph
    from hwbridge.msg import TypeRegistry

__all__ = [
    "LOG_FORMAT",
    "Context",
    "RobotFileArg",
    "emit_json",
    "get_registry",
    "json_line",
    "no_such_path",
    "open_graph",
    "robot_argument",
    "show_logs",
    "stderr_console",
    "warnings_as_notes",
]

LOG_FORMAT = "%(levelname)s %(name)s: %(message)s"
"""How a log record reads on stderr (``WARNING hwbridge.board: ...``): the lines of a log, as
long-running commands such as ``up`` print them."""


@functools.cache
def stderr_console() -> Console:
    """A rich console on stderr (imports rich on first use: most commands never need it)."""
    from rich.console import Console

    return Console(stderr=True, soft_wrap=True)


def json_line(data: Any) -> str:
    """``data`` as one line of strict JSON (``--json`` output), newline included.

    A float that JSON cannot hold (a Range's +-inf, a magnetometer's NaN on overflow) is written
    as the string ``"Infinity"``, ``"-Infinity"`` or ``"NaN"``: Python's bare ``Infinity`` and
    ``NaN`` tokens would stop jq and most other JSON readers.
    """
    try:
        return json.dumps(data, allow_nan=False) + "\n"
    except ValueError:  # only then walk the data
        return json.dumps(_finite(data), allow_nan=False) + "\n"


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return "NaN" if math.isnan(value) else "Infinity" if value > 0 else "-Infinity"
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(item) for item in value]
    return value


def emit_json(data: Any) -> None:
    """Write ``data`` to stdout as one line of JSON and flush (so pipes see it at once)."""
    sys.stdout.write(json_line(data))
    sys.stdout.flush()


def no_such_path(value: str | Path, param: str, known: str = "") -> typer.BadParameter:
    """The usage error (exit status 2) for an input path on the command line that does not
    exist, in the words Click uses for ``exists=True`` (``Invalid value for 'ROBOT.yaml': Path
    'nope.yaml' does not exist.``), for the arguments that cannot use it: those that also take a
    name (``known``: what such names are) or that are read only in some cases."""
    return typer.BadParameter(
        f"Path {str(value)!r} does not exist{f' (nor is it {known})' if known else ''}.",
        param_hint=[param],
    )


RobotFileArg = Annotated[
    Path,
    typer.Argument(metavar="ROBOT.yaml", exists=True, dir_okay=False, help="The robot file."),
]
"""The ROBOT.yaml argument of the commands that read a robot file (``up``, ``robot check``,
``show`` and ``acl``): a file that exists, else the usage error Click gives."""


def robot_argument(value: str, param: str) -> str:
    """A ROBOT argument as given (a robot file's path, or a packaged robot's name without a
    suffix: ``diffbot``); the usage error of :func:`no_such_path` if it is neither."""
    from hwbridge.emulator.board import ready_robots

    if Path(value).exists():
        return value
    ready = ready_robots()
    if not Path(value).suffix and value in ready:
        return value
    raise no_such_path(value, param, f"a ready robot: {', '.join(ready)}")


class _LogHandler(logging.StreamHandler):  # type: ignore[type-arg]
    """The root logger's handler that :func:`show_logs` puts on stderr."""


class _NoteFormatter(logging.Formatter):
    """Warnings and errors as the command's own lines read (``warning: ...``, ``error: ...``);
    the info and debug lines that ``-v`` shows as a log's (:data:`LOG_FORMAT`)."""

    def __init__(self) -> None:
        super().__init__(LOG_FORMAT)

    def formatMessage(self, record: logging.LogRecord) -> str:
        if record.levelno >= logging.WARNING:
            label = "error" if record.levelno >= logging.ERROR else "warning"
            return f"{label}: {record.message}"
        return super().formatMessage(record)


def show_logs(level: int) -> None:
    """Log records of ``level`` and above on stderr, as :data:`LOG_FORMAT` says; unless the
    root logger already has handlers (a test's, in-process), as :func:`logging.basicConfig`."""
    logging.basicConfig(level=level, handlers=[_LogHandler()])
    for handler in logging.getLogger().handlers:
        if isinstance(handler, _LogHandler):  # (also one an earlier run in-process made)
            handler.setFormatter(logging.Formatter(LOG_FORMAT))


def warnings_as_notes() -> None:
    """For a command that prints its own ``warning: ...`` lines (``record``, ``play``): the
    library's warnings and errors read the same (``warning: /x.mcap ends early ...``), not as a
    log's ``WARNING hwbridge.recorder: ...``, so that one command does not warn in two styles."""
    for handler in logging.getLogger().handlers:
        if isinstance(handler, _LogHandler):
            handler.setFormatter(_NoteFormatter())


@dataclass(frozen=True)
class Context:
    """Options given before the subcommand (``hwbridge --msg-path DIR msg show ...``)."""

    msg_path: tuple[Path, ...] = ()
    endpoint: str | None = None
    domain: str | None = None
    zenoh_config: Path | None = None


def _options(ctx: typer.Context) -> Context:
    obj = ctx.find_root().obj
    return obj if isinstance(obj, Context) else Context()


def get_registry(ctx: typer.Context) -> TypeRegistry:
    """The type registry for this invocation's --msg-path and HWBRIDGE_MSG_PATH."""
    from hwbridge.msg import registry

    return registry(_options(ctx).msg_path)


def open_graph(ctx: typer.Context) -> Graph:
    """Attach to the running graph (--endpoint, HWBRIDGE_ENDPOINT or the default loopback)."""
    from hwbridge.graph import Graph, GraphConfig

    options = _options(ctx)
    connect = [options.endpoint] if options.endpoint else None
    config = GraphConfig.attached(connect, options.domain)
    if options.zenoh_config is not None:
        config = dataclasses.replace(
            config, config_file=options.zenoh_config, connect=tuple(connect or ())
        )
    graph = Graph(config)
    msg_path = options.msg_path
    if msg_path:
        graph.registry = get_registry(ctx)
    # else the graph builds the default registry (HWBRIDGE_MSG_PATH) if and when it needs one
    return graph
