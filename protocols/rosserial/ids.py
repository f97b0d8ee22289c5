"""Reserved topic ids and control message types of rosserial protocol v2.

The ids are the constants of ``rosserial_msgs/TopicInfo`` (a test checks them against the
bundled definition). A service endpoint's TopicInfo comes on its base id + 0 for its publisher
half and + 1 for its subscriber half; user topics start at 100.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Final

__all__ = [
    "FIRST_USER_TOPIC",
    "LOG_TYPE",
    "PARAM_SERVICE",
    "TIME_TYPE",
    "TOPIC_INFO_TYPE",
    "ReservedId",
]


class ReservedId(IntEnum):
    """Topic ids below 100 with a fixed meaning (``rosserial_msgs/TopicInfo`` constants)."""

    PUBLISHER = 0
    """Device -> host: TopicInfo of a publisher. Host -> device, empty: "request topics"."""
    SUBSCRIBER = 1
    SERVICE_SERVER = 2
    """Service server: TopicInfo of its publisher half (2) and subscriber half (3)."""
    SERVICE_CLIENT = 4
    """Service client: TopicInfo of its publisher half (4) and subscriber half (5)."""
    PARAMETER_REQUEST = 6
    LOG = 7
    TIME = 10
    TX_STOP = 11


FIRST_USER_TOPIC: Final = 100
"""Smallest topic id the client library gives a user topic (subscriber slot 0)."""
TOPIC_INFO_TYPE: Final = "rosserial_msgs/TopicInfo"
LOG_TYPE: Final = "rosserial_msgs/Log"
PARAM_SERVICE: Final = "rosserial_msgs/RequestParam"
TIME_TYPE: Final = "std_msgs/Time"
