"""``hwbridge topic|service|param|node``: ROS-style tools attached to a running graph.

Tools that only move or count bytes (``topic list``, ``topic hz``, ``node list``...) never load
the message registry: ``hwbridge.msg`` (rosbags, numpy) and YAML are imported where a command
decodes, encodes or parses.

A topic may carry a type this host has no definition of (a board's own message package): the
bridge publishes its bytes under the board's type name and md5. ``topic list``, ``info``, ``hz``
and ``bw`` work as for any topic; ``topic echo`` shows such messages as their type, md5 and
bytes in hex (``{type, md5, raw}``), saying once on stderr which definition is missing.
"""

from __future__ import annotations

import itertools
import statistics
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from hwbridge.cli.common import emit_json, json_line, open_graph
from hwbridge.cli.livetopics import (
    GRACE,
    await_publisher,
    check_field,
    echo_target,
    live_type,
    name_argument,
    note,
    pub_arguments,
    refuse_other_type,
)
from hwbridge.errors import (
    HwBridgeError,
    HwBridgeTimeoutError,
    MessageTypeError,
    NoServerError,
    ProtocolMismatchError,
    UnknownTypeError,
)
from hwbridge.graph import ANY_TYPE, Graph, GraphSnapshot, RawMessage
from hwbridge.graph.discovery import LiveGraph, did_you_mean

if TYPE_CHECKING:
    from hwbridge.msg import TypeRegistry

__all__ = ["node_app", "param_app", "service_app", "topic_app"]

topic_app = typer.Typer(help="Topics: list, echo, pub, hz, bw, info, type.", no_args_is_help=True)
service_app = typer.Typer(help="Services: list, call, type.", no_args_is_help=True)
param_app = typer.Typer(
    help="Parameters: list, get, set, delete, load, dump.", no_args_is_help=True
)
node_app = typer.Typer(help="Nodes: list.", no_args_is_help=True)

JsonOpt = Annotated[bool, typer.Option("--json", help="Machine-readable JSON output.")]
TopicArg = Annotated[str, typer.Argument(metavar="TOPIC", help="Topic name, e.g. /odom")]
WaitOpt = Annotated[
    float, typer.Option("--wait", help="Seconds to wait for discovery before giving up.")
]
KeepWaitingOpt = Annotated[
    bool,
    typer.Option(
        "--wait",
        help="Keep waiting until the topic appears (default: give up after 2 s of discovery).",
    ),
]


def _snapshot(graph: Graph, wait: float) -> GraphSnapshot:
    return graph.snapshot(timeout=max(wait, 0.2))


# ---------------------------------------------------------------------- topic
@topic_app.command("list")
def topic_list(
    ctx: typer.Context,
    verbose: Annotated[bool, typer.Option("-v", "--verbose", help="Show nodes too.")] = False,
    as_json: JsonOpt = False,
    wait: WaitOpt = 1.0,
) -> None:
    """List topics that have publishers or subscribers."""
    with open_graph(ctx) as graph:
        snapshot = _snapshot(graph, wait)
    rows = []
    for name in sorted(snapshot.topics()):
        pubs = [e for e in snapshot.of_kind("pub") if e.name == name]
        subs = [e for e in snapshot.of_kind("sub") if e.name == name]
        types = sorted(snapshot.topics()[name] - {ANY_TYPE}) or [ANY_TYPE]
        rows.append(
            {
                "topic": name,
                "types": types,
                "publishers": sorted({e.node for e in pubs}),
                "subscribers": sorted({e.node for e in subs}),
            }
        )
    if as_json:
        emit_json(rows)
        return
    for row in rows:
        if verbose:
            typer.echo(
                f"{row['topic']} [{', '.join(row['types'])}] "
                f"{len(row['publishers'])} publisher(s), {len(row['subscribers'])} subscriber(s)"
            )
        else:
            typer.echo(row["topic"])


@topic_app.command("type")
def topic_type(ctx: typer.Context, topic: TopicArg, wait: WaitOpt = 1.0) -> None:
    """Print the type of a topic."""
    topic = name_argument(topic)
    with open_graph(ctx) as graph:
        known = _snapshot(graph, wait).topics()
    types = sorted(known.get(topic, set()) - {ANY_TYPE})
    if not types:
        raise HwBridgeError(
            f"no publisher or typed subscriber on {topic}{did_you_mean(topic, known)} "
            "(see 'hwbridge topic list')"
        )
    typer.echo("\n".join(types))


@topic_app.command("info")
def topic_info(
    ctx: typer.Context, topic: TopicArg, as_json: JsonOpt = False, wait: KeepWaitingOpt = False
) -> None:
    """Type, md5, publishers and subscribers of a topic."""
    topic = name_argument(topic)
    with open_graph(ctx) as graph:
        live = LiveGraph(graph)
        if not live.wait(lambda: topic in live.topics(), GRACE):
            unknown = f"nothing publishes or subscribes {topic}{did_you_mean(topic, live.topics())}"
            if not wait:
                raise HwBridgeError(f"{unknown} (see 'hwbridge topic list')")
            note(f"{unknown} yet; waiting until something does (Ctrl-C stops)")
            live.wait(lambda: topic in live.topics(), None)
        snapshot = _snapshot(graph, 0.2)
        registry = graph.registry
    entities = [e for e in snapshot.entities if e.kind in ("pub", "sub") and e.name == topic]
    types = [
        {"type": t, "md5": _md5_or_unknown(registry, t)}
        for t in sorted({e.type for e in entities} - {ANY_TYPE})
    ]
    publishers = sorted({e.node for e in entities if e.kind == "pub"})
    subscribers = sorted({e.node for e in entities if e.kind == "sub"})
    if as_json:
        emit_json(
            {"topic": topic, "types": types, "publishers": publishers, "subscribers": subscribers}
        )
        return
    for entry in types:
        typer.echo(f"Type: {entry['type']} (md5 {entry['md5']})")
    typer.echo("\nPublishers:")
    for name in publishers or ["(none)"]:
        typer.echo(f" * {name}")
    typer.echo("\nSubscribers:")
    for name in subscribers or ["(none)"]:
        typer.echo(f" * {name}")


def _md5_or_unknown(registry: TypeRegistry, type_name: str) -> str:
    try:
        return registry.md5(type_name)
    except HwBridgeError:
        return "unknown type"


@topic_app.command("echo")
def topic_echo(
    ctx: typer.Context,
    topic: Annotated[
        str,
        typer.Argument(
            metavar="TOPIC[/FIELD...]",
            help="Topic name, e.g. /odom, optionally followed by a field: "
            "/odom/pose/pose/position, /joint_states/position/0",
        ),
    ],
    count: Annotated[
        int | None, typer.Option("-n", "--count", min=1, help="Exit after N messages.")
    ] = None,
    as_json: JsonOpt = False,
    raw: Annotated[bool, typer.Option("--hex", help="Print payload bytes in hex.")] = False,
    timeout: Annotated[
        float | None, typer.Option("--timeout", help="Fail if no message within SECONDS.")
    ] = None,
    wait: KeepWaitingOpt = False,
) -> None:
    """Print messages on a topic as YAML (``---`` between them), like rostopic echo.

    As rostopic does, ``TOPIC/FIELD/...`` prints one field of each message: the longest
    published topic that starts the name is the topic, the rest a path of fields and list
    indexes. If nothing publishes the topic after 2 s of discovery, the command says so (with
    the published topics whose names are close) and fails, unless ``--wait`` (or
    ``--timeout``) asks it to keep waiting.

    A message of a type with no definition here is shown as its type, md5 and bytes in hex:
    ``{type, md5, raw}``. One whose type is defined here differently (another md5) is refused:
    decoding it would print wrong values (``--hex`` shows its bytes).
    """
    topic = name_argument(topic, fields=True)
    done = threading.Event()
    lock = threading.Lock()
    seen = [0]
    failed: list[Exception] = []

    def show(message: RawMessage) -> None:
        with lock:
            if done.is_set():
                return
            try:
                text = renderer.render(message)
                if text is not None:
                    sys.stdout.write(text)
                    sys.stdout.flush()
            except (ProtocolMismatchError, BrokenPipeError) as exc:
                # A closed stdout (``| head -1``) ends the command as in the main thread: the
                # error is raised there, where Click ends a broken pipe quietly with status 1.
                failed.append(exc)
                done.set()
                return
            seen[0] += 1
            if count is not None and seen[0] >= count:
                done.set()

    started = time.monotonic()
    with open_graph(ctx) as graph:
        live = LiveGraph(graph)
        target = echo_target(live, topic, timeout, wait, started)
        name, field = target
        if field and raw:
            raise typer.BadParameter(
                f"--hex prints whole messages: {name} has no field selection with it"
            )
        if field:
            check_field(graph, live, name, field)
        renderer = _Renderer(graph, as_json, raw, field)
        graph.node(f"hwbridge_echo_{graph.zid[:8]}").subscriber(name, ANY_TYPE, show, raw=True)
        while not done.wait(0.1):
            if timeout is not None and not seen[0] and time.monotonic() - started > timeout:
                raise HwBridgeTimeoutError(f"no message on {topic} within {timeout:g} s")
    if failed:
        raise failed[0]


class _Renderer:
    """Text for each message ``topic echo`` prints (called under its lock)."""

    def __init__(
        self, graph: Graph, as_json: bool, hex_only: bool, field: list[str] | None = None
    ) -> None:
        self.graph = graph
        self.as_json = as_json
        self.hex_only = hex_only
        self.field = field or []
        """Field path to print of each message (``TOPIC/FIELD...``), or all of it."""
        self._undecodable: dict[tuple[str, str], bool] = {}
        """(type, md5) -> True if shown raw (the reason was said once on stderr)."""

    def render(self, message: RawMessage) -> str | None:
        if self.hex_only:
            if self.as_json:
                return json_line(
                    {"topic": message.topic, "type": message.type, "hex": message.data.hex()}
                )
            return message.data.hex() + "\n---\n"
        from hwbridge import msg

        value: Any
        if self._raw_only(message):
            if self.field:
                sys.stderr.write(f"cannot select a field of a {message.type} message\n")
                return None
            value = {"type": message.type, "md5": message.md5, "raw": message.data.hex()}
        else:
            try:
                value = msg.to_dict(msg.decode(message.data, message.type, self.graph.registry))
            except HwBridgeError as exc:
                sys.stderr.write(f"cannot decode a {message.type} message: {exc}\n")
                return None
            try:
                value = msg.pick(value, self.field)
            except HwBridgeError as exc:
                sys.stderr.write(f"{message.topic}: {exc}\n")
                return None
        if self.as_json:
            return json_line(value)
        return msg.dump_yaml(value).removesuffix("...\n") + "---\n"

    def _raw_only(self, message: RawMessage) -> bool:
        """Whether ``message`` is shown as bytes: its type is unknown here, or known with
        another md5 (another definition). Says why on stderr, once per type and md5."""
        key = (message.type, message.md5)
        known = self._undecodable.get(key)
        if known is not None:
            return known
        reason = ""
        if not message.type:
            reason = "a message without a type (not published through hwbridge?)"
        else:
            try:
                ours = self.graph.registry.message(message.type).md5
            except UnknownTypeError:
                reason = f"no definition of {message.type} here: add its package with --msg-path"
            else:
                if ours != message.md5:
                    raise ProtocolMismatchError(
                        f"{message.topic}: the publisher sends {message.type} with md5 "
                        f"{message.md5 or '?'}, but the definition of {message.type} here has md5 "
                        f"{ours}: the two sides disagree on its fields, so its values cannot be "
                        "shown (use the publisher's definition with --msg-path, or --hex)"
                    )
        if reason:
            sys.stderr.write(f"{reason}; showing raw bytes\n")
            sys.stderr.flush()
        self._undecodable[key] = bool(reason)
        return bool(reason)


@topic_app.command("pub")
def topic_pub(
    ctx: typer.Context,
    topic: TopicArg,
    type_or_values: Annotated[
        str | None,
        typer.Argument(
            metavar="[TYPE]",
            help="Message type, e.g. geometry_msgs/Twist (default: the topic's type on the graph).",
        ),
    ] = None,
    values: Annotated[
        str | None,
        typer.Argument(metavar="[YAML]", help="Field values, e.g. '{linear: {x: 0.2}}'."),
    ] = None,
    once: Annotated[bool, typer.Option("-1", "--once", help="Publish once and exit.")] = False,
    rate: Annotated[
        float | None, typer.Option("-r", "--rate", min=0.001, help="Publish repeatedly at HZ.")
    ] = None,
    count: Annotated[
        int | None, typer.Option("-n", "--count", min=1, help="With -r: stop after N messages.")
    ] = None,
    file: Annotated[
        Path | None, typer.Option("-f", "--file", exists=True, dir_okay=False, help="YAML file.")
    ] = None,
    wait: Annotated[
        float, typer.Option("--wait", help="Seconds to wait for a subscriber before publishing.")
    ] = 2.0,
) -> None:
    """Publish a message (once with -1, repeatedly with -r), like rostopic pub.

    TYPE may be left out when the topic is on the graph (something publishes or subscribes
    it): its type there is used. A TYPE that differs from it is refused.
    """
    topic = name_argument(topic)
    type_name, values = pub_arguments(type_or_values, values)
    if values is not None and file is not None:
        raise typer.BadParameter("give values or --file, not both")
    if once and rate is not None:
        raise typer.BadParameter("-1 and -r exclude each other")
    from hwbridge import msg

    text = file.read_text() if file is not None else values or "{}"
    with open_graph(ctx) as graph:
        live = LiveGraph(graph)
        deadline = time.monotonic() + wait
        if type_name is None:
            type_name = live_type(live, topic)
        else:

            def subscribed() -> bool:
                return any(e.name == topic for e in live.entities("sub"))

            live.wait(subscribed, wait)
            refuse_other_type(topic, type_name, live.users(topic))
        message = msg.from_yaml(type_name, text, graph.registry)
        pub = graph.node(f"hwbridge_pub_{graph.zid[:8]}").publisher(topic, type_name)
        if not pub.wait_for_subscribers(max(deadline - time.monotonic(), 0.5)):
            sys.stderr.write(
                f"warning: no subscriber on {topic} after {wait:g} s; publishing anyway\n"
            )
        if rate is None:
            pub.publish(message)
            time.sleep(0.1)  # let Zenoh flush before the session closes
            return
        period = 1.0 / rate
        next_time = time.monotonic()
        sent = 0
        while count is None or sent < count:
            pub.publish(message)
            sent += 1
            next_time += period
            time.sleep(max(0.0, next_time - time.monotonic()))
        time.sleep(0.1)


class _RateMeter:
    """Arrival statistics over a sliding window (for hz and bw)."""

    def __init__(self, window: int) -> None:
        self.stamps: deque[float] = deque(maxlen=window + 1)
        self.sizes: deque[int] = deque(maxlen=window)
        self.total = 0
        self.lock = threading.Lock()

    def add(self, size: int) -> None:
        with self.lock:
            self.stamps.append(time.monotonic())
            self.sizes.append(size)
            self.total += 1

    def report(self) -> dict[str, Any] | None:
        with self.lock:
            stamps = list(self.stamps)
            sizes = list(self.sizes)
        if len(stamps) < 2:
            return None
        gaps = [b - a for a, b in itertools.pairwise(stamps)]
        span = stamps[-1] - stamps[0]
        mean_gap = span / len(gaps)
        return {
            "rate_hz": 1.0 / mean_gap if mean_gap > 0 else float("inf"),
            "min_s": min(gaps),
            "max_s": max(gaps),
            "std_dev_s": statistics.pstdev(gaps),
            "window": len(gaps),
            "bytes_per_s": sum(sizes[-len(gaps) :]) / span if span > 0 else float("inf"),
            "mean_bytes": sum(sizes) / len(sizes),
            "messages": self.total,
        }


def _measure(
    ctx: typer.Context,
    topic: str,
    window: int,
    duration: float | None,
    as_json: bool,
    kind: str,
    wait: bool,
) -> None:
    topic = name_argument(topic)
    meter = _RateMeter(window)
    with open_graph(ctx) as graph:
        await_publisher(LiveGraph(graph), topic, wait)
        graph.node(f"hwbridge_{kind}_{graph.zid[:8]}").subscriber(
            topic, ANY_TYPE, lambda m: meter.add(len(m.data)), raw=True
        )
        started = time.monotonic()
        while duration is None or time.monotonic() - started < duration:
            time.sleep(min(1.0, duration or 1.0))
            stats = meter.report()
            if stats is None:
                sys.stderr.write(f"no new messages on {topic}\n")
                continue
            if as_json:
                emit_json({"topic": topic, **stats})
            elif kind == "hz":
                typer.echo(
                    f"average rate: {stats['rate_hz']:.3f}\n"
                    f"\tmin: {stats['min_s']:.3f}s max: {stats['max_s']:.3f}s "
                    f"std dev: {stats['std_dev_s']:.5f}s window: {stats['window']}"
                )
            else:
                typer.echo(
                    f"average: {_human_bytes(stats['bytes_per_s'])}/s\n"
                    f"\tmean: {_human_bytes(stats['mean_bytes'])} window: {stats['window']}"
                )


def _human_bytes(value: float) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if abs(value) < 1000 or unit == "GB":
            return f"{value:.2f}{unit}"
        value /= 1000
    return f"{value:.2f}GB"


WindowOpt = Annotated[int, typer.Option("-w", "--window", min=1, help="Messages in the window.")]
DurationOpt = Annotated[
    float | None, typer.Option("--duration", min=0.1, help="Stop after SECONDS.")
]


@topic_app.command("hz")
def topic_hz(
    ctx: typer.Context,
    topic: TopicArg,
    window: WindowOpt = 1000,
    duration: DurationOpt = None,
    as_json: JsonOpt = False,
    wait: KeepWaitingOpt = False,
) -> None:
    """Print the publishing rate of a topic every second."""
    _measure(ctx, topic, window, duration, as_json, "hz", wait)


@topic_app.command("bw")
def topic_bw(
    ctx: typer.Context,
    topic: TopicArg,
    window: WindowOpt = 100,
    duration: DurationOpt = None,
    as_json: JsonOpt = False,
    wait: KeepWaitingOpt = False,
) -> None:
    """Print the bandwidth used by a topic every second."""
    _measure(ctx, topic, window, duration, as_json, "bw", wait)


# ---------------------------------------------------------------------- service
@service_app.command("list")
def service_list(ctx: typer.Context, as_json: JsonOpt = False, wait: WaitOpt = 1.0) -> None:
    """List services that have a server."""
    with open_graph(ctx) as graph:
        services = _snapshot(graph, wait).services()
    if as_json:
        emit_json([{"service": k, "types": sorted(v)} for k, v in sorted(services.items())])
        return
    for name in sorted(services):
        typer.echo(name)


def _service_type(graph: Graph, name: str, wait: float, appear: float = 0.0) -> str:
    """The type of service ``name``, discovered within ``wait`` s; when it has no server yet,
    looked for again until ``appear`` s have passed (a board's services leave the graph while
    its session is negotiated again, for a moment after a link loss or a reset)."""
    deadline = time.monotonic() + max(wait, appear)
    services = _snapshot(graph, wait).services()
    told = False
    while not services.get(name) and time.monotonic() < deadline:
        if not told and sys.stderr.isatty():
            sys.stderr.write(f"waiting for a server of {name} (up to {appear:g} s)\n")
            told = True
        time.sleep(min(0.2, max(0.0, deadline - time.monotonic())))
        services = _snapshot(graph, 0.2).services()
    types = sorted(services.get(name, set()))
    if not types:
        raise HwBridgeError(
            f"no server for service {name}{did_you_mean(name, services)} "
            "(see 'hwbridge service list')"
        )
    return types[0]


@service_app.command("type")
def service_type(
    ctx: typer.Context,
    name: Annotated[str, typer.Argument(metavar="SERVICE")],
    wait: WaitOpt = 1.0,
) -> None:
    """Print the type of a service."""
    name = name_argument(name, "service")
    with open_graph(ctx) as graph:
        typer.echo(_service_type(graph, name, wait))


@service_app.command("call")
def service_call(
    ctx: typer.Context,
    name: Annotated[str, typer.Argument(metavar="SERVICE")],
    request: Annotated[
        str | None, typer.Argument(metavar="[YAML]", help="Request fields, e.g. '{data: true}'.")
    ] = None,
    srv_type: Annotated[
        str | None, typer.Option("--type", help="Service type (default: as discovered).")
    ] = None,
    timeout: Annotated[
        float,
        typer.Option(
            "--timeout",
            help="Seconds to wait for the answer, and before that for a server if none is "
            "there yet.",
        ),
    ] = 5.0,
    as_json: JsonOpt = False,
    wait: WaitOpt = 1.0,
) -> None:
    """Call a service and print the response, like rosservice call."""
    import yaml

    from hwbridge import msg

    name = name_argument(name, "service")
    try:
        data = yaml.safe_load(request or "{}")
    except yaml.YAMLError as exc:
        raise MessageTypeError(f"request is not valid YAML: {exc}") from exc
    with open_graph(ctx) as graph:
        deadline = time.monotonic() + max(wait, timeout)
        resolved_type = srv_type or _service_type(graph, name, wait, timeout)
        node = graph.node(f"hwbridge_call_{graph.zid[:8]}")
        while True:
            try:
                response = node.call(name, resolved_type, data or {}, timeout=timeout)
                break
            except NoServerError:
                # Listed, but its server went before the request reached it (a board's session
                # ending): nothing acted on the request, so it goes again once a server is back.
                if deadline - time.monotonic() < 0.5:
                    raise
                _service_type(graph, name, 0.2, deadline - time.monotonic())
                timeout = max(0.5, deadline - time.monotonic())
        result = msg.to_dict(response)
    if as_json:
        emit_json(result)
    else:
        typer.echo(msg.dump_yaml(result).rstrip("\n") if result else "{}")


# ---------------------------------------------------------------------- param
ParamName = Annotated[str, typer.Argument(metavar="NAME", help="Parameter name, e.g. /robot/rate")]


def _namespace_argument(namespace: str) -> str:
    """A parameter namespace (``param load``, ``dump``): a parameter name, also written with the
    '/' that ends a namespace (``/robot/``, as rosparam takes it)."""
    return name_argument(namespace.rstrip("/") or "/", "parameter")


@param_app.command("list")
def param_list(ctx: typer.Context, as_json: JsonOpt = False) -> None:
    """List parameter names."""
    with open_graph(ctx) as graph:
        names = graph.params.names()
    if as_json:
        emit_json(names)
    else:
        for name in names:
            typer.echo(name)


@param_app.command("get")
def param_get(ctx: typer.Context, name: ParamName, as_json: JsonOpt = False) -> None:
    """Print a parameter (a namespace prints as a mapping)."""
    from hwbridge.graph import ParamError

    name = name_argument(name, "parameter")
    with open_graph(ctx) as graph:
        try:
            value = graph.params.get(name)
        except ParamError as exc:
            if not str(exc).startswith("no parameter"):
                raise
            names = graph.params.names()
            namespaces = {n.rsplit("/", depth)[0] for n in names for depth in (1, 2)}
            raise ParamError(f"{exc}{did_you_mean(name, {*names, *namespaces} - {''})}") from exc
    if as_json:
        emit_json(value)
    else:
        from hwbridge import msg

        typer.echo(msg.dump_yaml(value).removesuffix("\n...\n").rstrip("\n"))


@param_app.command("set")
def param_set(
    ctx: typer.Context,
    name: ParamName,
    value: Annotated[
        str, typer.Argument(metavar="VALUE", help="A YAML value: 3, 0.5, true, [1, 2], text")
    ],
) -> None:
    """Set a parameter; the value is parsed as YAML."""
    import yaml

    name = name_argument(name, "parameter")
    try:
        parsed = yaml.safe_load(value)
    except yaml.YAMLError as exc:
        raise HwBridgeError(f"value is not valid YAML: {exc}") from exc
    with open_graph(ctx) as graph:
        graph.params.set(name, parsed)


@param_app.command("delete")
def param_delete(ctx: typer.Context, name: ParamName) -> None:
    """Delete a parameter or a whole namespace."""
    name = name_argument(name, "parameter")
    with open_graph(ctx) as graph:
        graph.params.delete(name)


@param_app.command("load")
def param_load(
    ctx: typer.Context,
    file: Annotated[Path, typer.Argument(metavar="FILE.yaml", exists=True, dir_okay=False)],
    namespace: Annotated[str, typer.Argument(metavar="[NAMESPACE]")] = "/",
) -> None:
    """Set every parameter in a YAML file (under NAMESPACE), like rosparam load."""
    import yaml

    namespace = _namespace_argument(namespace)
    try:
        data = yaml.safe_load(file.read_text())
    except yaml.YAMLError as exc:
        raise HwBridgeError(f"{file}: not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise HwBridgeError(f"{file}: expected a mapping of names to values at the top")
    with open_graph(ctx) as graph:
        for key, value in data.items():
            graph.params.set(f"{namespace.rstrip('/')}/{str(key).lstrip('/')}", value)


@param_app.command("dump")
def param_dump(
    ctx: typer.Context,
    file: Annotated[Path | None, typer.Argument(metavar="[FILE.yaml]", dir_okay=False)] = None,
    namespace: Annotated[str, typer.Option("--namespace", help="Only this namespace.")] = "/",
) -> None:
    """Write every parameter as YAML (to FILE, or stdout), like rosparam dump."""
    namespace = _namespace_argument(namespace)
    with open_graph(ctx) as graph:
        value = graph.params.get(namespace, {})
    from hwbridge import msg

    text = msg.dump_yaml(value)
    if file is None:
        sys.stdout.write(text)
    else:
        file.write_text(text)


# ---------------------------------------------------------------------- node
@node_app.command("list")
def node_list(ctx: typer.Context, as_json: JsonOpt = False, wait: WaitOpt = 1.0) -> None:
    """List nodes alive on the graph."""
    with open_graph(ctx) as graph:
        nodes = _snapshot(graph, wait).nodes
    if as_json:
        emit_json(nodes)
    else:
        for name in nodes:
            typer.echo(name)
