"""How a process joins the hwbridge graph: Zenoh configuration with safe defaults.

Two shapes cover one machine:

- **embedded** (the bridge, or any program that wants to own the graph): a Zenoh *router* that
  listens on one loopback endpoint only (``tcp/127.0.0.1:7447`` unless told otherwise), with
  multicast scouting and gossip off, so nothing leaves the machine and nothing else must run.
- **attached** (CLI tools, other nodes): a Zenoh *client* connected to that endpoint.

Across machines, give endpoints (``listen``/``connect``) or a full Zenoh config file (JSON5) for
TLS, user/password authentication and access control; see docs/graph.md.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from hwbridge.errors import HwBridgeError

if TYPE_CHECKING:
    import zenoh

__all__ = [
    "DEFAULT_ENDPOINT",
    "ENV_CONFIG",
    "ENV_DOMAIN",
    "ENV_ENDPOINT",
    "GraphConfig",
]

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
ENV_ENDPOINT = "HWBRIDGE_ENDPOINT"
"""Overrides the loopback endpoint the bridge listens on and tools connect to."""
ENV_CONFIG = "HWBRIDGE_ZENOH_CONFIG"
"""Path of a Zenoh JSON5 config file used instead of the built-in defaults."""
ENV_DOMAIN = "HWBRIDGE_DOMAIN"
"""Graph domain: graphs with different domains on one Zenoh network do not see each other."""

Mode = Literal["router", "peer", "client"]


@dataclass(frozen=True)
class GraphConfig:
    """Everything needed to open a Zenoh session for the graph."""

    mode: Mode = "client"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    domain: str = "0"
    config_file: Path | None = None
    """A Zenoh JSON5 file; its settings are kept, then mode/listen/connect given here apply."""
    extra: dict[str, str] = field(default_factory=dict)
    """Further Zenoh settings as ``{"path/in/config": "json5 value"}``."""

    @classmethod
    def from_file(cls, path: str | Path, mode: Mode, domain: str | None = None) -> GraphConfig:
        """Everything from a Zenoh JSON5 file (endpoints, TLS, auth, access control)."""
        return cls(
            mode=mode, domain=domain or os.environ.get(ENV_DOMAIN, "0"), config_file=Path(path)
        )

    @classmethod
    def embedded(
        cls, listen: Sequence[str] | None = None, domain: str | None = None
    ) -> GraphConfig:
        """A router that owns the graph, reachable on the loopback endpoint only."""
        return cls(
            mode="router",
            listen=_endpoints(listen),
            domain=domain or os.environ.get(ENV_DOMAIN, "0"),
            config_file=_env_file(),
        )

    @classmethod
    def attached(
        cls, connect: Sequence[str] | None = None, domain: str | None = None
    ) -> GraphConfig:
        """A client of a running bridge (or router) at ``connect``."""
        return cls(
            mode="client",
            connect=_endpoints(connect),
            domain=domain or os.environ.get(ENV_DOMAIN, "0"),
            config_file=_env_file(),
        )

    @classmethod
    def isolated(cls, domain: str = "0") -> GraphConfig:
        """A peer that neither listens nor connects: one process, nothing on the network."""
        return cls(mode="peer", domain=domain)

    def to_zenoh(self) -> zenoh.Config:
        """The Zenoh config object (imports Zenoh)."""
        import zenoh

        if self.config_file is not None:
            try:
                config: zenoh.Config = zenoh.Config.from_file(str(self.config_file))
            except (OSError, zenoh.ZError) as exc:
                raise HwBridgeError(f"cannot read Zenoh config {self.config_file}: {exc}") from exc
        else:
            config = zenoh.Config()
            # Safe defaults: no multicast discovery, no gossip, nothing but what is asked for.
            config.insert_json5("scouting/multicast/enabled", "false")
            config.insert_json5("scouting/gossip/enabled", "false")
            config.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
            config.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        config.insert_json5("mode", json.dumps(self.mode))
        if self.config_file is not None and self.listen:
            config.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        if self.config_file is not None and self.connect:
            config.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        _no_scouting_delay(config)
        for path, value in self.extra.items():
            config.insert_json5(path, value)
        return config

    def describe(self) -> str:
        """One line for logs and errors."""
        where = ", ".join(self.listen or self.connect) or (
            "endpoints from the file" if self.config_file else "no endpoints"
        )
        source = f" from {self.config_file}" if self.config_file else ""
        return f"Zenoh {self.mode} ({where}){source}, domain {self.domain}"


def _no_scouting_delay(config: zenoh.Config) -> None:
    """Open at once when nothing is scouted.

    Zenoh's ``scouting/delay`` holds ``zenoh.open`` of a router for 500 ms by default, time
    given to multicast scouting to find peers before the session is used. With multicast
    scouting off (hwbridge's default) there is nothing to wait for; the delay was most of the
    bridge's start-up time. A delay set in a config file, or multicast scouting enabled
    (Zenoh's own default when a file does not say), keeps Zenoh's behaviour.
    """
    if config.get_json("scouting/delay") == "null" and (
        config.get_json("scouting/multicast/enabled") == "false"
    ):
        config.insert_json5("scouting/delay", "0")


def _endpoints(given: Sequence[str] | None) -> tuple[str, ...]:
    """Endpoints given, else HWBRIDGE_ENDPOINT, else the config file's, else the default."""
    if given is not None:
        return tuple(given)
    endpoint = os.environ.get(ENV_ENDPOINT)
    if endpoint:
        return (endpoint,)
    return () if _env_file() is not None else (DEFAULT_ENDPOINT,)


def _env_file() -> Path | None:
    value = os.environ.get(ENV_CONFIG)
    return Path(value) if value else None
