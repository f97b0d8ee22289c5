"""The build tag of a firmware generated from a robot file (PROTOCOL.md 2.6.1).

``hwbridge firmware generate ROBOT.yaml --board NAME`` writes ``HWBRIDGE_BUILD_TAG`` into the
sketch; the board sends it in BOARD_INFO, and ``hwbridge up ROBOT.yaml`` compares it with the
tag of the robot file it brings up. One formula, here::

    <robot>/<board>@<the first 12 lowercase hex digits of SHA-256 over the robot file's bytes>
"""

from __future__ import annotations

import hashlib
import re
from typing import Final, NamedTuple

__all__ = ["BuildTag", "build_tag", "parse_build_tag"]

_TAG: Final = re.compile(r"(?P<robot>[^/@\n]+)/(?P<board>[^/@\n]+)@(?P<digest>[0-9a-f]{12})")


def build_tag(robot_name: str, board_name: str, robot_file_bytes: bytes) -> str:
    """The build tag of board ``board_name``'s firmware generated from a robot file named
    ``robot_name`` whose bytes are ``robot_file_bytes``."""
    digest = hashlib.sha256(robot_file_bytes).hexdigest()[:12]
    return f"{robot_name}/{board_name}@{digest}"


class BuildTag(NamedTuple):
    """A build tag's parts."""

    robot: str
    board: str
    digest: str


def parse_build_tag(text: str) -> BuildTag | None:
    """The parts of a build tag, or None if ``text`` is not of the form ``robot/board@12hex``."""
    match = _TAG.fullmatch(text)
    if match is None:
        return None
    return BuildTag(match["robot"], match["board"], match["digest"])
