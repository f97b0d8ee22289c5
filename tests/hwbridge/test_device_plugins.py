"""A device plugin from another distribution, found only through its entry point, used end to end:
a robot file names it, a virtual board runs its model, ``RobotRuntime`` (what ``hwbridge up``
runs) starts its host node, and the graph gets what the node derives. Nothing in ``hwbridge/`` or
``devices/`` names it (``tests/plugins/hwbridge_thermo``).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from hwbridge.emulator import VirtualBoard, load_board
from hwbridge.graph import Graph
from hwbridge.links import open_link
from hwbridge.robot import registry
from hwbridge.robot.config import load_robot
from hwbridge.robot.model import RobotFileError
from hwbridge.robot.runtime import RobotRuntime
from tests.netutil import free_port, wait_until

PLUGINS = Path(__file__).resolve().parents[1] / "plugins"


@pytest.fixture
def thermo_installed(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.syspath_prepend(str(PLUGINS))
    registry.refresh()
    yield
    monkeypatch.undo()
    registry.refresh()


def test_a_device_plugin_by_entry_point_end_to_end(thermo_installed: None, tmp_path: Path) -> None:
    assert "thermo" in registry.device_types()
    robot_file = tmp_path / "greenhouse.yaml"
    robot_file.write_text(
        "robot: greenhouse\n"
        "boards:\n"
        "  - name: node1\n"
        "    link: /dev/ttyACM0\n"
        "    protocol: native\n"
        "    namespace: /greenhouse\n"
        "    devices:\n"
        "      - {type: thermo, rate: 20, room_celsius: 27.0}\n"
    )
    board = VirtualBoard(load_board(str(robot_file)), seed=1)
    pty = open_link(f"pty://?symlink={tmp_path / 'ttyNODE1'}")
    board.start(pty)
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="thermo")
    robot = load_robot(robot_file).with_links({"node1": str(tmp_path / "ttyNODE1")})
    runtime = RobotRuntime(robot, graph)
    try:
        runtime.start()
        temperatures: list[Any] = []
        graph.node("watch").subscriber(
            "/greenhouse/temperature", "sensor_msgs/Temperature", temperatures.append
        )
        assert wait_until(lambda: len(temperatures) >= 3, 30), runtime.bridge.boards["node1"].info()
        assert float(temperatures[-1].temperature) == pytest.approx(27.0, abs=0.2)
        assert [d.device.type for d in runtime.devices] == ["thermo"]
    finally:
        runtime.stop()
        graph.close()
        board.stop()
        pty.close()


def test_robot_check_sees_the_plugin_settings(thermo_installed: None, tmp_path: Path) -> None:
    robot_file = tmp_path / "bad.yaml"
    robot_file.write_text(
        "robot: bad\nboards:\n  - name: b\n    link: pty://\n    devices:\n"
        "      - {type: thermo, rate: hot}\n"
    )
    with pytest.raises(
        RobotFileError, match=r"bad.yaml:6: board b: thermo: rate: expected a number"
    ):
        load_robot(robot_file)
