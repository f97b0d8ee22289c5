"""Devices of one robot that would publish one topic or serve one service: an error of the robot
file (:func:`hwbridge.robot.config.parse_robot` reports them, so ``robot check`` and ``up`` do)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

from hwbridge.robot.model import HostDeviceConfig, RobotBoardConfig
from hwbridge.robot.plugin import TopicUse

__all__ = ["topic_clashes"]


def _line(source: str) -> int:
    """The line of a ``FILE:LINE`` source."""
    _path, _sep, line = source.rpartition(":")
    return int(line) if line.isdigit() else 1


_VERBS: Final = {"publishes": "publish", "serves": "serve"}


def topic_clashes(
    boards: Sequence[RobotBoardConfig], hosts: Sequence[HostDeviceConfig]
) -> list[tuple[int, str]]:
    """Two devices that would publish one topic (or serve one service): a problem (line, text)
    at the later device's line, naming the earlier one's. Each plugin says what it uses with
    :meth:`~hwbridge.robot.plugin.DevicePlugin.topics`, resolved in its board's or its own
    namespace; a plugin that does not say is left out, and topics meant for many publishers
    (``/tf``) never clash."""
    from hwbridge.graph import GraphNameError, resolve_name
    from hwbridge.robot.registry import get_device

    problems: list[tuple[int, str]] = []

    placed = [(b.namespace, f"board {b.name}: {d.name}", d) for b in boards for d in b.devices]
    placed += [
        (h.namespace, f"host device {h.device.name} ({h.device.type})", h.device) for h in hosts
    ]
    owners: dict[tuple[str, str], tuple[str, int]] = {}
    for namespace, label, device in placed:
        line = _line(device.source)
        try:
            uses = get_device(device.type).topics(device.settings)
        except Exception as exc:  # noqa: BLE001 - a plugin's own bug, shown where it is used
            problems.append(
                (
                    line,
                    f"{label}: type {device.type} cannot list its topics: "
                    f"{type(exc).__name__}: {exc}",
                ),
            )
            continue
        if uses is None:  # the plugin does not say
            continue
        clashes: dict[tuple[str, int], dict[str, list[str]]] = {}
        mine: set[tuple[str, str]] = set()
        for use in uses:
            if not isinstance(use, TopicUse) or use.shared or use.use not in _VERBS:
                continue
            try:
                name = resolve_name(use.name, namespace)
            except GraphNameError as exc:
                problems.append((line, f"{label}: topic {use.name!r}: {exc}"))
                continue
            key = (use.use, name)
            if key in mine:
                continue
            mine.add(key)
            if key in owners:
                clashes.setdefault(owners[key], {}).setdefault(_VERBS[use.use], []).append(name)
            else:
                owners[key] = (label, line)
        for (other, other_line), found in clashes.items():
            what = "; ".join(f"{verb} {' and '.join(names)}" for verb, names in found.items())
            problems.append(
                (
                    line,
                    f"{label}: would {what}, as {other} at line {other_line} does: two devices "
                    "cannot share one; give one of them other topic names in its settings",
                )
            )
    return problems
