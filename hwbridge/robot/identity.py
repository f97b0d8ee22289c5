"""The build tag of a firmware generated from a robot file (PROTOCOL.md 2.6.1).

``hwbridge firmware generate ROBOT.yaml --board NAME`` writes ``HWBRIDGE_BUILD_TAG`` into the
sketch; the board sends it in BOARD_INFO, and ``hwbridge up ROBOT.yaml`` compares it with the
tag of the robot file it brings up. One formula, here::

    <robot>/<board>@<the first 12 lowercase hex digits of SHA-256 over the robot file's bytes>

(:func:`parse_build_tag` splits one; it lives with the firmware identity in
:mod:`hwbridge.protocols.base`, so that the bridge reads tags without importing robots.)
"""

from __future__ import annotations

import hashlib

from hwbridge.protocols.base import BuildTag, parse_build_tag

__all__ = ["BuildTag", "build_tag", "parse_build_tag"]


def build_tag(robot_name: str, board_name: str, robot_file_bytes: bytes) -> str:
    """The build tag of board ``board_name``'s firmware generated from a robot file named
    ``robot_name`` whose bytes are ``robot_file_bytes``."""
    digest = hashlib.sha256(robot_file_bytes).hexdigest()[:12]
    return f"{robot_name}/{board_name}@{digest}"
