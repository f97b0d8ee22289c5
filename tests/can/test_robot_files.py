"""Robot files name CAN boards by node id in their links: eight boards on one bus check out, a
node id out of range is reported with its line. (Two boards of one file on one node id are
refused when the second link opens: test_links.)"""

from __future__ import annotations

import pytest

from hwbridge.errors import HwBridgeError
from hwbridge.links import create_link
from hwbridge.links.can import CanLink
from hwbridge.robot.config import parse_robot

BOARDS = "\n".join(
    f"  - name: pod{n}\n    link: can://slcan/dev/ttyACM0/node{n}?bitrate=1000000\n"
    f"    protocol: native\n    devices: []"
    for n in range(1, 9)
)


def test_eight_boards_on_one_bus() -> None:
    robot = parse_robot(f"robot: pods\nboards:\n{BOARDS}\n", "pods.yaml")
    assert [b.name for b in robot.boards] == [f"pod{n}" for n in range(1, 9)]
    links = [create_link(b.link) for b in robot.boards]
    assert all(isinstance(link, CanLink) for link in links)
    assert [link.node for link in links if isinstance(link, CanLink)] == list(range(1, 9))


def test_bad_node_id_reported_with_its_line() -> None:
    text = (
        "robot: pods\nboards:\n  - name: pod1\n    link: can://virtual/bus/node1\n"
        "    devices: []\n  - name: pod2\n    link: can://virtual/bus/node200\n    devices: []\n"
    )
    with pytest.raises(HwBridgeError) as info:
        parse_robot(text, "pods.yaml")
    assert "pods.yaml:7" in str(info.value)
    assert "1..127" in str(info.value)
