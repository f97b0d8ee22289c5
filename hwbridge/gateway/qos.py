"""ROS 2 QoS for the gateway's topics: the kinds a user names, the defaults, per-topic rules.

Kept free of rclpy and Zenoh so that robot files and the command line can check QoS rules
without loading either.

Which ROS 2 endpoints match (a subscription asks for at most what a publisher offers):

- a **reliable** publisher reaches both a default subscription (``create_subscription(T, topic,
  cb, 10)``: reliable, volatile) and a ``qos_profile_sensor_data`` one (best effort); a
  **best effort** publisher reaches only best effort subscriptions. So everything the gateway
  publishes is reliable unless a rule says otherwise. With a keep-last history a reliable
  publisher never waits for a slow subscription: the oldest unacknowledged sample is dropped.
- a **best effort** subscription takes both reliable and best effort publishers (a teleop node
  with default QoS, a driver with sensor QoS); a reliable one only reliable publishers. So the
  gateway's subscriptions (commands to boards) are best effort unless a rule says otherwise.
- a **transient local** (latched) publisher reaches volatile and transient local
  subscriptions; a transient local subscription (tf2's ``/tf_static`` listener) needs one.
"""

from __future__ import annotations

import fnmatch
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Final

__all__ = [
    "KINDS",
    "ROSOUT_KIND",
    "QosKind",
    "QosRules",
    "check_kind",
    "check_pattern",
    "default_kind",
    "parse_rule",
]


@dataclass(frozen=True)
class QosKind:
    """A QoS profile by name: what ``--qos PATTERN=KIND`` and a robot file's ``ros: {qos:}``
    say."""

    name: str
    reliable: bool
    transient_local: bool
    depth: int
    doc: str


KINDS: Final[dict[str, QosKind]] = {
    kind.name: kind
    for kind in (
        QosKind(
            "reliable",
            reliable=True,
            transient_local=False,
            depth=10,
            doc="reliable, volatile, keep last 10; published: reaches default and sensor-data "
            "subscribers (the default for everything published into ROS 2); subscribed: "
            "takes reliable publishers only",
        ),
        QosKind(
            "sensor",
            reliable=False,
            transient_local=False,
            depth=5,
            doc="best effort, volatile, keep last 5 (qos_profile_sensor_data); published: "
            "reaches best-effort (sensor-data) subscribers only; subscribed: takes reliable "
            "and best-effort publishers (the default for topics from ROS 2 to the graph)",
        ),
        QosKind(
            "tf",
            reliable=True,
            transient_local=False,
            depth=100,
            doc="reliable, volatile, keep last 100, as tf2's broadcaster (the default for /tf)",
        ),
        QosKind(
            "latched",
            reliable=True,
            transient_local=True,
            depth=100,
            doc="reliable, transient local, keep last 100: late subscribers get the last "
            "messages, as tf2's static broadcaster (the default for /tf_static)",
        ),
    )
}
"""The kinds a user can name, by name."""

ROSOUT_KIND: Final = QosKind(
    "rosout",
    reliable=True,
    transient_local=True,
    depth=1000,
    doc="reliable, transient local, keep last 1000, as rclpy's own /rosout",
)

_NAME_CHARS: Final = re.compile(r"^[A-Za-z0-9_/~*?\[\]!-]+$")


def default_kind(topic: str, direction: str) -> str:
    """The kind a topic gets without a rule: ``direction`` is ``to_ros`` (the gateway
    publishes in ROS 2) or ``from_ros`` (it subscribes there)."""
    if topic == "/tf_static" or topic.endswith("/tf_static"):
        return "latched"
    if topic == "/tf" or topic.endswith("/tf"):
        return "tf"
    return "reliable" if direction == "to_ros" else "sensor"


def check_pattern(pattern: str) -> str | None:
    """Why ``pattern`` cannot choose topics (None when it can): a shell pattern on full
    topic names."""
    if not pattern:
        return "the topic pattern is empty"
    if not pattern.startswith(("/", "*")):
        return (
            f"topic pattern {pattern!r} must be a full name starting with / "
            "(or *), e.g. /diffbot/imu or '/diffbot/*'"
        )
    if not _NAME_CHARS.match(pattern):
        return (
            f"topic pattern {pattern!r} has characters no topic name has "
            "(names are letters, digits, _ and /; patterns add * ? [...])"
        )
    if pattern.rfind("[") > pattern.rfind("]"):
        return f"topic pattern {pattern!r}: '[' without its ']'"
    return None


def check_kind(kind: str) -> str | None:
    """Why ``kind`` is no QoS kind (None when it is)."""
    if kind in KINDS:
        return None
    return f"unknown QoS kind {kind!r}; known: {', '.join(KINDS)}"


def parse_rule(text: str) -> tuple[str, str]:
    """``PATTERN=KIND`` as (pattern, kind); :class:`ValueError` says what is wrong."""
    pattern, sep, kind = text.rpartition("=")
    if not sep:
        raise ValueError(f"{text!r}: write PATTERN=KIND, e.g. '/diffbot/imu=sensor'")
    why = check_pattern(pattern) or check_kind(kind)
    if why is not None:
        raise ValueError(f"{text!r}: {why}")
    return pattern, kind


@dataclass(frozen=True)
class QosRules:
    """Per-topic QoS rules, in order: the first rule whose pattern matches a topic names its
    kind; topics no rule matches get :func:`default_kind`."""

    rules: tuple[tuple[str, str], ...] = ()

    @classmethod
    def of(cls, *groups: Iterable[tuple[str, str]]) -> QosRules:
        """Rules from groups in order of precedence (the command line's before the robot
        file's)."""
        return cls(tuple(rule for group in groups for rule in group))

    def kind(self, topic: str, direction: str) -> QosKind:
        for pattern, name in self.rules:
            if fnmatch.fnmatchcase(topic, pattern):
                return KINDS[name]
        return KINDS[default_kind(topic, direction)]

    def as_args(self, option: str = "--qos") -> Sequence[str]:
        """The rules as command-line arguments (``--qos PATTERN=KIND`` each)."""
        return [arg for pattern, kind in self.rules for arg in (option, f"{pattern}={kind}")]
