"""A Zenoh access-control policy for one robot, written from what the robot declares.

On one machine every local process may drive the robot, as with ROS. A robot on a network needs
more: people on the network should see its sensors without being able to move it. Zenoh checks
every message a router receives (*ingress*) and forwards (*egress*) against the router's
``access_control`` rules, matched by key expression and by the connecting user's name. This
module turns the running robot's topics and services (a discovery snapshot of the graph) into
such rules:

- **operators** may do everything under the robot's graph domain (publish commands, call
  services, set parameters);
- **viewers** may subscribe to the robot's topics and list the graph, and nothing else: their
  publications (``cmd_vel``, ``wheel_targets``, any board subscriber), service calls and
  parameter requests are dropped by the router;
- anyone else is refused (the default is ``deny``), and the user/password check at connection
  time keeps unknown clients out altogether.

The bridge's own nodes run in the router's session, which Zenoh does not filter, so the host
nodes keep driving the boards.
"""

from __future__ import annotations

import json
import secrets
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from hwbridge.graph.snapshot import GraphSnapshot

__all__ = ["RobotSurface", "access_control", "router_config", "surface_of"]

_ALL_MESSAGES = (
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
)
_DISCOVERY_MESSAGES = ("liveliness_token", "declare_liveliness_subscriber", "liveliness_query")
_BOTH = ("ingress", "egress")


@dataclass(frozen=True)
class RobotSurface:
    """What a robot offers on the graph, sorted by name."""

    readable: tuple[str, ...]
    """Topics the robot publishes: sensors, odometry, tf, diagnostics."""
    commands: tuple[str, ...]
    """Topics the robot subscribes to: anything published there moves or changes it."""
    services: tuple[str, ...]
    """Services the robot serves."""

    @property
    def empty(self) -> bool:
        return not (self.readable or self.commands or self.services)


def _under(name: str, namespaces: Sequence[str]) -> bool:
    for namespace in namespaces:
        base = namespace.rstrip("/")
        if not base or name == base or name.startswith(base + "/"):
            return True
    return False


def surface_of(
    snapshot: GraphSnapshot,
    namespaces: Sequence[str] = ("/",),
    exclude_sessions: Iterable[str] = (),
) -> RobotSurface:
    """The robot's topics and services in ``snapshot``.

    Only names under one of ``namespaces`` count (``/`` takes everything), and entities announced
    by ``exclude_sessions`` (the asking tool's own session) are left out. A topic the robot both
    publishes and subscribes to is a command: publishing to it reaches the robot.
    """
    excluded = set(exclude_sessions)
    published: set[str] = set()
    subscribed: set[str] = set()
    served: set[str] = set()
    for entity in snapshot.entities:
        if entity.session in excluded or not entity.name or not _under(entity.name, namespaces):
            continue
        if entity.kind == "pub":
            published.add(entity.name)
        elif entity.kind == "sub":
            subscribed.add(entity.name)
        elif entity.kind == "srv":
            served.add(entity.name)
    return RobotSurface(
        readable=tuple(sorted(published - subscribed)),
        commands=tuple(sorted(subscribed)),
        services=tuple(sorted(served)),
    )


def _topic_key(prefix: str, topic: str) -> str:
    # The same layout as Graph.topic_key: graph names are already valid key chunks.
    return f"{prefix}/t{topic}"


def access_control(
    surface: RobotSurface,
    prefix: str,
    viewers: Sequence[str] = ("viewer",),
    operators: Sequence[str] = ("operator",),
) -> dict[str, Any]:
    """Zenoh's ``access_control`` section: operators may do anything under ``prefix`` (the
    graph's key prefix, ``hwbridge/<domain>``), viewers may
    read the robot's topics (its commands too, which shows what drives it) and discover the graph.

    Viewers get ``declare_subscriber`` on ingress and ``put`` on egress only: a rule allowing
    ``put`` on ingress would let them publish.
    """
    topics = sorted({*surface.readable, *surface.commands})
    rules: list[dict[str, object]] = [
        {
            "id": "discovery",
            "messages": list(_DISCOVERY_MESSAGES),
            "flows": list(_BOTH),
            "permission": "allow",
            # `**` never matches an `@` chunk: discovery must be named.
            "key_exprs": [f"{prefix}/@/**"],
        },
        {
            "id": "operate",
            "messages": list(_ALL_MESSAGES),
            "flows": list(_BOTH),
            "permission": "allow",
            "key_exprs": [f"{prefix}/**", f"{prefix}/@/**"],
        },
    ]
    policies: list[dict[str, object]] = []
    subjects: list[dict[str, object]] = []
    if operators:
        subjects.append({"id": "operators", "usernames": list(operators)})
        policies.append({"id": "operators", "rules": ["operate"], "subjects": ["operators"]})
    if viewers:
        subjects.append({"id": "viewers", "usernames": list(viewers)})
        viewer_rules = ["discovery"]
        if topics:
            keys = [_topic_key(prefix, topic) for topic in topics]
            rules.append(
                {
                    "id": "subscribe",
                    "messages": ["declare_subscriber"],
                    "flows": ["ingress"],
                    "permission": "allow",
                    "key_exprs": keys,
                }
            )
            rules.append(
                {
                    "id": "receive",
                    "messages": ["put"],
                    "flows": ["egress"],
                    "permission": "allow",
                    "key_exprs": keys,
                }
            )
            viewer_rules += ["subscribe", "receive"]
        policies.append({"id": "viewers", "rules": viewer_rules, "subjects": ["viewers"]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def router_config(
    surface: RobotSurface,
    *,
    robot: str,
    prefix: str,
    listen: Sequence[str],
    users_file: str,
    viewers: Sequence[str] = ("viewer",),
    operators: Sequence[str] = ("operator",),
) -> str:
    """A whole Zenoh router config (JSON5 text) for the bridge: ``listen`` endpoints, no
    scouting, user/password login checked against ``users_file`` (``name:password`` lines), and
    :func:`access_control` for ``surface``. Comments say what each part is for."""

    def dump(value: object) -> str:
        return json.dumps(value, indent=2)

    lines = [
        f"// Zenoh router config for robot {robot} (graph keys {prefix}/...), written by",
        "// `hwbridge robot acl` from the topics and services the running robot declared.",
        "// Start the robot with it:  hwbridge --zenoh-config THIS_FILE up ROBOT.yaml",
        f"// Logins come from {users_file}: one `name:password` line per user.",
        f"// Operators ({', '.join(operators) or 'none'}) may do everything; viewers "
        f"({', '.join(viewers) or 'none'}) may only",
        "// subscribe to the robot's topics and list the graph. The robot subscribes to these,",
        "// so only operators may publish to them:",
        *(f"//   {name}" for name in surface.commands),
        "// and only operators may call its services"
        + (":" if surface.services else " (it has none now)."),
        *(f"//   {name}" for name in surface.services),
        "// Regenerate after adding devices: a new topic is not readable until it is listed.",
        "{",
        f"  listen: {{ endpoints: {json.dumps(list(listen))} }},",
        "  scouting: { multicast: { enabled: false }, gossip: { enabled: false } },",
        "  transport: {",
        "    auth: {",
        "      usrpwd: {",
        '        user: "bridge",',
        f"        password: {json.dumps(secrets.token_urlsafe(16))},",
        f"        dictionary_file: {json.dumps(users_file)},",
        "      },",
        "    },",
        "  },",
        "  access_control: "
        + dump(access_control(surface, prefix, viewers, operators)).replace("\n", "\n  ")
        + ",",
        "}",
    ]
    return "\n".join(lines) + "\n"
