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
import re
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
    "open_error",
    "zenoh_text",
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

    def to_zenoh(self) -> zenoh.Config:
        """The Zenoh config object (imports Zenoh)."""
        import zenoh

        if self.config_file is not None:
            try:
                config: zenoh.Config = zenoh.Config.from_file(str(self.config_file))
            except (OSError, zenoh.ZError) as exc:
                raise HwBridgeError(
                    f"cannot read Zenoh config {self.config_file}: {zenoh_text(exc)}"
                ) from exc
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


_RUST_PLACE = re.compile(r"\s*\bat \S+\.rs:\d+\.?")
"""Where in Zenoh's Rust source an error was raised (`` at /root/.cargo/.../tcp.rs:61.``)."""
_BUSY = re.compile(r"bound to (?P<endpoint>\S+?):?\s*\[.*address already in use", re.I | re.S)
_UNREACHABLE = re.compile(r"unable to connect to any of", re.I)
_MALFORMED = re.compile(r"Endpoints must be of the form [^:]*: (?P<endpoint>[^\"]*)")
"""Zenoh's words for an endpoint without its protocol (``127.0.0.1:7447``)."""


_PARSE_PLACE = re.compile(r"-->\s*(?P<line>\d+):(?P<column>\d+)")


def zenoh_text(exc: BaseException) -> str:
    """A Zenoh error's message on one line, without the Rust source places it names (a JSON5
    syntax error's drawing becomes ``line L, column C: what was expected``)."""
    text = _RUST_PLACE.sub("", str(exc)).strip()
    place = _PARSE_PLACE.search(text)
    if place is not None and "\n" in text:
        what = text.splitlines()[-1].strip().lstrip("= ").strip()
        return f"line {place.group('line')}, column {place.group('column')}: {what}"
    return " ".join(text.split())


def open_error(config: GraphConfig, exc: BaseException) -> HwBridgeError:
    """What to tell a user whose session with ``config`` did not open, from Zenoh's error:
    the one place a Zenoh opening error becomes an :class:`HwBridgeError`."""
    raw = str(exc)
    busy = _BUSY.search(raw)
    if busy is not None or (config.mode != "client" and "address already in use" in raw.lower()):
        endpoint = busy.group("endpoint") if busy else ", ".join(config.listen) or "the endpoint"
        return HwBridgeError(
            f"{endpoint} is already in use (another 'hwbridge up', 'connect' or 'graph' "
            f"is running?); stop it, or run this one on another endpoint with "
            f"--listen {_next_port(endpoint)}"
        )
    malformed = _MALFORMED.search(_RUST_PLACE.sub("", raw))
    if malformed is not None:
        endpoint = malformed.group("endpoint")
        example = f"tcp/{endpoint}" if re.fullmatch(r"[\w.-]+:\d+", endpoint) else DEFAULT_ENDPOINT
        return HwBridgeError(
            f"{endpoint!r} is not a Zenoh endpoint: write PROTOCOL/ADDRESS, e.g. {example}"
        )
    where = ", ".join(config.listen or config.connect) or "the endpoints of the config file"
    if config.mode == "client" and _UNREACHABLE.search(raw):
        reason = f"nothing answers at {where}"
    else:
        reason = zenoh_text(exc)
    hint = ""
    if config.mode == "client":
        hint = (
            "; is a bridge running? start one with 'hwbridge connect URL', "
            "'hwbridge up ROBOT.yaml' or 'hwbridge graph' (or set HWBRIDGE_ENDPOINT)"
        )
        if config.config_file is not None:
            # A refused login or TLS handshake ends the same way as no bridge at all.
            hint += (
                f"; if one is, check that the credentials or certificates in "
                f"{config.config_file} are the ones it accepts"
            )
    return HwBridgeError(f"cannot join the graph ({config.describe()}): {reason}{hint}")


def _next_port(endpoint: str) -> str:
    """``endpoint`` one port up (``tcp/127.0.0.1:7448`` for ``tcp/127.0.0.1:7447``)."""
    head, sep, port = endpoint.rpartition(":")
    if sep and port.isdigit() and int(port) < 65535:
        return f"{head}:{int(port) + 1}"
    return "tcp/127.0.0.1:7448"
