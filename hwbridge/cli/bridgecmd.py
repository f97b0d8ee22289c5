"""``hwbridge connect`` (run the bridge) and ``hwbridge board`` (ask it about its boards)."""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from hwbridge.cli.common import Context, emit_json, get_registry, open_graph
from hwbridge.errors import HwBridgeError, HwBridgeTimeoutError

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from hwbridge.graph import GraphConfig
    from hwbridge.links.discovery import SerialPort

__all__ = [
    "ListenOption",
    "ParamsOption",
    "QuietOption",
    "board_app",
    "connect",
    "owner_config",
    "read_params",
    "show_board_logs",
    "wait_for_signal",
]

board_app = typer.Typer(
    help="Boards: scan the serial ports; list, info, stats of the running bridge's.",
    no_args_is_help=True,
)
log = logging.getLogger("hwbridge.cli")

ParamsOption = Annotated[
    Path | None,
    typer.Option("--params", exists=True, dir_okay=False, help="YAML file of initial parameters."),
]
"""``--params`` of the commands that own the graph (``connect``, ``up``)."""
ListenOption = Annotated[
    str | None,
    typer.Option(
        "--listen", help="Zenoh endpoint for CLI tools and nodes (default tcp/127.0.0.1:7447)."
    ),
]
"""``--listen`` of the commands that own the graph."""
QuietOption = Annotated[
    bool,
    typer.Option(
        "--quiet",
        "-q",
        help="Hide the boards' info log lines (shown by default; warnings and errors still show).",
    ),
]
"""``--quiet`` of the commands that run boards (``connect``, ``up``)."""


class _BoardLogHandler(logging.StreamHandler):  # type: ignore[type-arg]
    """Where :func:`show_board_logs` prints (one per process, whatever calls it)."""


def show_board_logs(quiet: bool) -> None:
    """Show the boards' own log lines on stderr, named by board, as rosserial does: INFO and
    above (debug too with ``-vv``; WARNING and above with ``--quiet``), whatever ``-v`` says
    for the bridge's messages."""
    from hwbridge.bridge.endpoints import BOARD_LOG

    logger = logging.getLogger(BOARD_LOG)
    for old in [h for h in logger.handlers if isinstance(h, _BoardLogHandler)]:
        logger.removeHandler(old)
    handler = _BoardLogHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s %(message)s"))
    logger.addHandler(handler)
    logger.setLevel(
        logging.WARNING if quiet else min(logging.INFO, logging.getLogger().getEffectiveLevel())
    )
    logger.propagate = False  # printed once, here, not again by the root's handler


def connect(
    ctx: typer.Context,
    urls: Annotated[
        list[str],
        typer.Argument(
            metavar="URL...",
            help="Board links: /dev/ttyACM0, serial:///dev/ttyUSB0?baud=57600, "
            "usb:VID:PID[:SERIAL], auto (the one port with a known board), "
            "socket://host:port, tcp-listen://:11411, spy+URL ...",
        ),
    ],
    protocol: Annotated[
        str, typer.Option("--protocol", "-p", help="auto, native or rosserial.")
    ] = "auto",
    baud: Annotated[
        int | None, typer.Option("--baud", "-b", min=50, help="Serial baud rate (default 115200).")
    ] = None,
    namespace: Annotated[
        str, typer.Option("--namespace", "-n", help="Graph namespace for the boards' topics.")
    ] = "/",
    name: Annotated[
        list[str] | None, typer.Option("--name", help="Board name (once per URL, in order).")
    ] = None,
    start_delay: Annotated[
        float,
        typer.Option(
            "--start-delay",
            min=0,
            help="Seconds of silence before probing a board that has not spoken (default: probe "
            "at once, then again with backoff while a reset board boots). For boards whose "
            "bootloader takes bytes after a reset as an upload (a Mega: 2): the bridge then "
            "never keeps talking to a silent board, so a reset one is not held there.",
        ),
    ] = 0.0,
    service_timeout: Annotated[
        float,
        typer.Option(
            "--service-timeout",
            metavar="SECONDS",
            help="Seconds to wait for a service answer, both ways: graph calls of board "
            "services and board calls of graph services (above 0, at most 86400).",
        ),
    ] = 5.0,
    params: ParamsOption = None,
    listen: ListenOption = None,
    quiet: QuietOption = False,
) -> None:
    """Connect boards to the graph and keep them connected until Ctrl-C.

    A usb:VID:PID[:SERIAL] or auto URL is resolved to its port when the bridge starts (as in
    a robot file; 'hwbridge board scan' lists the ports). The boards' log lines (INFO and
    above) show on stderr; --quiet hides the info ones."""
    from hwbridge.bridge import BoardSpec, Bridge, check_service_timeout
    from hwbridge.graph import Graph
    from hwbridge.protocols.registry import get_protocol

    if protocol != "auto":
        try:
            get_protocol(protocol)
        except HwBridgeError as exc:
            raise typer.BadParameter(str(exc), param_hint="--protocol") from exc
    try:
        check_service_timeout(service_timeout)
    except HwBridgeError as exc:
        raise typer.BadParameter(str(exc), param_hint="--service-timeout") from exc
    names = name or []
    if len(names) > len(urls):
        raise typer.BadParameter("more --name options than URLs", param_hint="--name")
    links = resolve_connect_links(urls, names)
    initial = read_params(params)
    show_board_logs(quiet)
    config = owner_config(ctx, listen)
    graph = Graph(config)
    graph.registry = get_registry(ctx)
    bridge = Bridge(graph, params=initial)
    try:
        for index, (url, default_name) in enumerate(links):
            spec = BoardSpec(
                url,
                protocol=protocol,
                baud=baud,
                namespace=namespace,
                name=names[index] if index < len(names) else default_name,
                start_delay=start_delay,
                service_timeout=service_timeout,
            )
            bridge.add_board(spec)
        sys.stderr.write(
            f"hwbridge: bridging {', '.join(urls)} on {config.describe()}; Ctrl-C stops\n"
        )
        sys.stderr.flush()
        wait_for_signal()
    finally:
        bridge.stop()
        graph.close()


def resolve_connect_links(
    urls: list[str],
    names: list[str],
    list_ports: Callable[[], Sequence[SerialPort]] | None = None,
) -> list[tuple[str, str | None]]:
    """``connect``'s URLs with the ``usb:`` and ``auto`` ones resolved to their ports (as
    ``hwbridge up`` resolves a robot file's), each with the board name its port gives (the
    device's, ``ttyACM0``, rather than a long by-id one; None for other URLs); HwBridgeError
    naming every link that matches no port, several, or one another link has."""
    from hwbridge.links.discovery import resolve_links

    whats = [f"board {names[i]}" if i < len(names) else f"URL {i + 1}" for i in range(len(urls))]
    results = resolve_links(list(zip(whats, urls, strict=True)), list_ports)
    problems: list[str] = []
    links: list[tuple[str, str | None]] = []
    for what, url in zip(whats, urls, strict=True):
        result = results.get(what)
        if result is None:
            links.append((url, None))
        elif result.problem is not None or result.resolved is None:
            problems.append(f"{what}: {result.problem}")
        else:
            port = result.port
            device = port.device if port is not None else result.resolved
            log.info("%s: link %s is %s", what, url, port.describe() if port else device)
            links.append((result.resolved, Path(device).name or None))
    if problems:
        raise HwBridgeError("; ".join(problems))
    return links


def owner_config(ctx: typer.Context, listen: str | None) -> GraphConfig:
    """The graph configuration of a process that owns the graph (``connect``, ``up``): the
    endpoint from ``--listen`` or the global options, the domain and any Zenoh config file."""
    from hwbridge.graph import GraphConfig

    options = ctx.find_root().obj
    endpoint = listen or (options.endpoint if isinstance(options, Context) else None)
    config = GraphConfig.embedded([endpoint] if endpoint else None, _domain(ctx))
    if isinstance(options, Context) and options.zenoh_config is not None:
        config = GraphConfig(
            mode="router",
            listen=(endpoint,) if endpoint else (),
            domain=config.domain,
            config_file=options.zenoh_config,
        )
    return config


def read_params(path: Path | None) -> dict[str, Any]:
    """Initial parameters from a YAML file of names and values (``--params``)."""
    if path is None:
        return {}
    import yaml

    try:
        loaded = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"{path}:{mark.line + 1}" if mark is not None else str(path)
        raise HwBridgeError(f"{where}: not valid YAML: {exc.problem or exc.context}") from exc
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise HwBridgeError(f"{path}: cannot read parameters: {exc}") from exc
    if not isinstance(loaded, dict):
        raise HwBridgeError(f"{path}: expected a mapping of parameter names to values")
    return {("/" + str(k).lstrip("/")): v for k, v in loaded.items()}


def wait_for_signal() -> None:
    """Block until SIGINT or SIGTERM (see :mod:`hwbridge.cli.stopping`)."""
    from hwbridge.cli.stopping import wait_for_stop

    wait_for_stop()


def _domain(ctx: typer.Context) -> str | None:
    options = ctx.find_root().obj
    return options.domain if isinstance(options, Context) else None


def _board_names(ctx: typer.Context, wait: float) -> list[tuple[str, str, str]]:
    with open_graph(ctx) as graph:
        boards = graph.snapshot(timeout=max(wait, 0.2)).of_kind("board")
    return sorted((e.node, e.name, e.type) for e in boards)


def _board_info(ctx: typer.Context, board: str, timeout: float) -> dict[str, Any]:
    from hwbridge.bridge.board import board_key

    with open_graph(ctx) as graph:
        replies = graph.session.get(board_key(graph.prefix, board), timeout=timeout)
        for reply in replies:
            if reply.ok is not None:
                info: dict[str, Any] = json.loads(bytes(reply.ok.payload.to_bytes()))
                return info
            if reply.err is not None:
                raise HwBridgeError(f"board {board}: {reply.err.payload.to_string()}")
    raise HwBridgeTimeoutError(f"no board named {board!r} answered (see 'hwbridge board list')")


def _only_board(ctx: typer.Context, board: str | None) -> str:
    """``board``, or the name of the one board on the graph when it is not given."""
    if board is not None:
        return board
    names = sorted({name for name, _url, _protocol in _board_names(ctx, 1.0)})
    if not names:
        raise HwBridgeError(
            "no board is connected: start a bridge with 'hwbridge connect URL' (or "
            "'hwbridge up ROBOT.yaml'); 'hwbridge board list' shows the boards"
        )
    if len(names) > 1:
        raise HwBridgeError(
            f"{len(names)} boards are connected ({', '.join(names)}): name one, "
            f"e.g. hwbridge board info {names[0]}"
        )
    return names[0]


JsonOpt = Annotated[bool, typer.Option("--json", help="Machine-readable JSON output.")]
BoardArg = Annotated[
    str | None,
    typer.Argument(
        metavar="[BOARD]", help="Board name (hwbridge board list); default: the only one."
    ),
]


@board_app.command("list")
def board_list(ctx: typer.Context, as_json: JsonOpt = False) -> None:
    """List boards the bridge keeps connected (whether connected right now or not)."""
    rows = _board_names(ctx, 1.0)
    if as_json:
        emit_json([{"board": n, "url": u, "protocol": p} for n, u, p in rows])
        return
    for board, url, proto in rows:
        typer.echo(f"{board}\t{url}\t{proto}")


@board_app.command("info")
def board_info(ctx: typer.Context, board: BoardArg = None, as_json: JsonOpt = False) -> None:
    """State, protocol and topics of a board."""
    info = _board_info(ctx, _only_board(ctx, board), 2.0)
    info.pop("stats", None)
    info.pop("link", None)
    info.pop("transport", None)
    _print(info, as_json)


@board_app.command("stats")
def board_stats(ctx: typer.Context, board: BoardArg = None, as_json: JsonOpt = False) -> None:
    """Link statistics of a board: frames, bytes, checksum errors, gaps, retransmits, RTT."""
    board = _only_board(ctx, board)
    info = _board_info(ctx, board, 2.0)
    _print(
        {
            "board": board,
            "protocol": info.get("protocol"),
            "stats": info.get("stats"),
            "link": info.get("link"),
            **({"transport": info["transport"]} if info.get("transport") else {}),
        },
        as_json,
    )


@board_app.command("scan")
def board_scan(
    probe: Annotated[
        bool,
        typer.Option(
            "--probe",
            help="Open each port and tell whether a hwbridge (native) or rosserial board "
            "answers (this usually resets an Arduino; a port in use is reported, not taken).",
        ),
    ] = False,
    probe_timeout: Annotated[
        float,
        typer.Option(
            "--probe-timeout",
            metavar="SECONDS",
            min=0.1,
            max=60,
            help="How long to listen on each port (they are probed together).",
        ),
    ] = 3.0,
    baud: Annotated[
        int | None,
        typer.Option("--baud", "-b", min=50, help="Baud rate to probe at (default 115200)."),
    ] = None,
    as_json: JsonOpt = False,
) -> None:
    """List the serial ports, the board or USB-serial chip behind each (by USB ID) and its
    stable /dev/serial/by-id name.

    A robot file's link may then be usb:VID:PID (or usb:VID:PID:SERIAL), or auto for the one
    port with a known board."""
    from hwbridge.links.discovery import ProbeResult, list_serial_ports, probe_port

    ports = list_serial_ports()
    probed: list[ProbeResult | None] = [None] * len(ports)
    if probe and ports:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(min(len(ports), 8)) as pool:
            probed = list(pool.map(lambda p: probe_port(p.device, probe_timeout, baud), ports))
    if as_json:
        rows = []
        for port, result in zip(ports, probed, strict=True):
            row = port.as_dict()
            if probe:
                row["protocol"] = result.protocol if result else None
                row["probe"] = result.describe() if result else None
            rows.append(row)
        emit_json(rows)
        return
    if not ports:
        typer.echo("no serial ports found")
        return
    header = ["PORT", "USB ID", "WHAT", *(["ANSWERS"] if probe else []), "BY-ID"]
    table = [header]
    for port, result in zip(ports, probed, strict=True):
        what = port.board or (port.description if port.description != "n/a" else "") or "-"
        table.append(
            [
                port.device,
                port.usb_id or "-",
                what,
                *([result.describe() if result else "-"] if probe else []),
                port.by_id or "-",
            ]
        )
    widths = [max(len(cells[i]) for cells in table) for i in range(len(header))]
    for cells in table:
        typer.echo("  ".join(c.ljust(w) for c, w in zip(cells, widths, strict=True)).rstrip())


def _print(data: dict[str, Any], as_json: bool) -> None:
    if as_json:
        emit_json(data)
    else:
        from hwbridge.msg import dump_yaml

        sys.stdout.write(dump_yaml(data))
