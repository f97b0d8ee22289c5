"""What the bridge says about the firmware a board runs (PROTOCOL.md 2.6.1).

A board's protocol may tell its firmware identity (:class:`~hwbridge.protocols.base.
FirmwareIdentity`: native boards do in BOARD_INFO, rosserial boards do not). :class:`FirmwareCheck`
compares it with this host: a schema or messages hash that differs from the host's means the
firmware was built with another hwbridge version, and a build tag that differs from the one
``hwbridge up`` expects means the board runs firmware generated from another robot file. It says
so once per board and distinct identity: a board that reconnects a hundred times with the same
firmware is warned about once; flashing other firmware is news again. An unknown identity (an
old board, rosserial) is never a warning.
"""

from __future__ import annotations

import functools
import logging
from typing import Any

from hwbridge.protocols.base import FirmwareIdentity, parse_build_tag
from hwbridge.protocols.msgtypes import TypeRegistry

__all__ = ["FirmwareCheck", "host_hashes", "host_identity", "library_version"]


def host_hashes(registry: TypeRegistry) -> tuple[str, str]:
    """(schema hash, messages hash) of firmware built with this hwbridge, its messages as
    ``registry`` defines them."""
    from hwbridge.firmware.gen_msgs import library_messages_hash
    from hwbridge.protocols.native.identity import schema_hash

    return schema_hash(), library_messages_hash(registry)


@functools.cache
def library_version() -> str:
    """The version of the HwBridge library this hwbridge carries (``library.properties``; empty
    if it cannot be read)."""
    from hwbridge.firmware.build import LIBRARY_DIR

    try:
        text = (LIBRARY_DIR / "library.properties").read_text(encoding="utf-8")
    except OSError:
        return ""
    for line in text.splitlines():
        key, _, value = line.partition("=")
        if key.strip() == "version":
            return value.strip()
    return ""


def host_identity(registry: TypeRegistry, version: str, name: str = "") -> FirmwareIdentity:
    """The identity of firmware built with this hwbridge (what the emulator's boards send, so
    that they match the host)."""
    schema, messages = host_hashes(registry)
    return FirmwareIdentity(
        version=version,
        name=name,
        library_version=library_version(),
        schema_hash=schema,
        messages_hash=messages,
    )


class FirmwareCheck:
    """Checks the firmware identity of each session of one board (see the module docstring).

    ``expected_build`` is the build tag of the robot file the board was brought up from
    (``hwbridge up``), ``robot_file`` that file's path for the messages."""

    def __init__(
        self,
        board: str,
        log: logging.Logger,
        registry: TypeRegistry,
        *,
        expected_build: str | None = None,
        robot_file: str = "",
    ) -> None:
        self.board = board
        self.log = log
        self.registry = registry
        self.expected_build = expected_build
        self.robot_file = robot_file
        self.identity: FirmwareIdentity | None = None
        """The identity of the board's last session (None: not told)."""
        self.problems: list[str] = []
        """What differs in it from this host, for ``hwbridge board info``."""
        self._seen: set[FirmwareIdentity] = set()
        self._host: tuple[str, str] | None = None

    def info(self) -> dict[str, Any] | None:
        """The firmware for ``hwbridge board info``: its items and ``problems`` (None: the board
        did not tell, or has not connected yet)."""
        if self.identity is None or not self.identity.known:
            return None
        return {**self.identity.as_dict(), "problems": list(self.problems)}

    def check(self, identity: FirmwareIdentity | None) -> None:
        """A session connected with ``identity``: remember it, and warn about what differs
        unless this identity of this board was already reported."""
        self.identity = identity
        if identity is None or not identity.known:
            self.problems = []
            return
        self.problems = self._hash_problems(identity)
        if identity in self._seen:
            return
        self._seen.add(identity)
        what = identity.firmware_name or identity.version or "without a name"
        if self.problems:
            self.log.warning(
                "%s: the board's firmware (%s) was built with another hwbridge version (%s); "
                "rebuild and upload the firmware with this hwbridge "
                "(regenerate a sketch's own headers with 'hwbridge firmware generate'), or the "
                "board and the host may not understand each other",
                self.board,
                what,
                "; ".join(self.problems),
            )
        self._check_build(identity)

    def _hash_problems(self, identity: FirmwareIdentity) -> list[str]:
        if self._host is None:
            self._host = host_hashes(self.registry)
        schema, messages = self._host
        problems = []
        if identity.schema_hash and identity.schema_hash != schema:
            problems.append(f"control schema hash {identity.schema_hash}, this host's {schema}")
        if identity.messages_hash and identity.messages_hash != messages:
            problems.append(
                f"message definitions hash {identity.messages_hash}, this host's {messages}"
            )
        return problems

    def _check_build(self, identity: FirmwareIdentity) -> None:
        if self.expected_build is None or parse_build_tag(identity.build_tag) is None:
            return
        where = f" ({self.robot_file})" if self.robot_file else ""
        if identity.build_tag == self.expected_build:
            self.log.info(
                "%s: the board runs the firmware generated from this robot file%s: %s",
                self.board,
                where,
                identity.build_tag,
            )
            return
        self.log.warning(
            "%s: the board runs a build of another robot file: its firmware's build tag is %s, "
            "this robot file's%s is %s; regenerate and upload the firmware from this file to "
            "match it",
            self.board,
            identity.build_tag,
            where,
            self.expected_build,
        )
