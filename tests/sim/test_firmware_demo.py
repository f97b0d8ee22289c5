"""``hwbridge demo --firmware`` (run_firmware_demo): DiffDriveBase for the ATmega328P in simavr
behind RobotRuntime and the host nodes; odometry within 0.5 % of the distance driven; the same
with ``--generated`` (the firmware generated from the robot file); the ``firmware sim`` command
prints the UART's URL first."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from hwbridge.emulator.demo import ROBOT_FILE
from hwbridge.emulator.firmware_demo import UNO_ROBOT_FILE
from hwbridge.errors import HwBridgeError
from hwbridge.firmware.sim import SimAvr
from hwbridge.firmware.sim.examples import build_example
from hwbridge.robot.config import load_robot
from tests.netutil import free_port


@pytest.fixture(scope="module")
def diffdrive_elf(runner: Path) -> Path:
    try:
        return build_example("DiffDriveBase", "uno")
    except HwBridgeError as exc:
        pytest.skip(f"DiffDriveBase does not build here: {str(exc).splitlines()[0]}")


def test_uno_robot_is_the_demo_robot_decoding_x2() -> None:
    """diffbot_uno.yaml: the same world as diffbot.yaml; the Uno decodes x2, so half the
    counts per turn; no pan servo (an Uno has no spare UART)."""
    robot, uno = load_robot(ROBOT_FILE), load_robot(UNO_ROBOT_FILE)
    assert uno.world == robot.world
    (before,) = [d for d in robot.board("base").devices if d.type == "diffdrive"]
    (after,) = [d for d in uno.board("base").devices if d.type == "diffdrive"]
    assert after.settings["counts_per_rev"] == before.settings["counts_per_rev"] / 2
    assert (robot.board("base").mcu, uno.board("base").mcu) == ("mega", "uno")
    assert "dynamixel" not in [d.type for d in uno.board("base").devices]


def test_firmware_demo(diffdrive_elf: Path, tmp_path: Path) -> None:
    """``hwbridge demo --firmware`` as a user runs it (the DiffDriveBase build is cached)."""
    _run_demo(tmp_path, [])


def test_generated_firmware_demo(runner: Path, tmp_path: Path) -> None:
    """``hwbridge demo --firmware --generated``: the firmware generated from diffbot_uno.yaml
    in simavr, the same world and host nodes, odometry within 0.5 %."""
    from hwbridge.sketchgen import generated_elf

    try:
        generated_elf(UNO_ROBOT_FILE, "uno", "base")  # built (and cached) before the clock runs
    except HwBridgeError as exc:
        pytest.skip(f"the generated firmware does not build here: {str(exc).splitlines()[0]}")
    output = _run_demo(tmp_path, ["--generated"])
    assert "the sketch generated from diffbot_uno.yaml" in output


def _run_demo(tmp_path: Path, extra: list[str]) -> str:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hwbridge = [sys.executable, "-m", "hwbridge", "--endpoint", endpoint]
    demo = subprocess.Popen(
        [
            *hwbridge,
            "demo",
            "--firmware",
            *extra,
            "--duration",
            "8",
            "--plot",
            str(tmp_path / "path.svg"),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
    )
    try:
        # the CLI, from another process, sees the firmware's topics on the demo's graph
        listed = ""
        for _ in range(40):
            time.sleep(0.5)
            done = subprocess.run(
                [*hwbridge, "topic", "list"],
                capture_output=True,
                text=True,
                timeout=30,
                check=False,
            )
            listed = done.stdout
            if all(t in listed for t in ("/diffbot/odom", "/diffbot/range", "/diffbot/imu")):
                break
        output, _ = demo.communicate(timeout=120)
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.wait(10)
    assert demo.returncode == 0, output
    for topic in ("/diffbot/odom", "/diffbot/range", "/diffbot/imu"):
        assert topic in listed, listed
    last = output.strip().splitlines()[-1]
    found = re.fullmatch(r"odometry error: (\d+\.\d{3})% of (\d+\.\d\d) m", last)
    assert found is not None, output
    assert float(found.group(2)) > 0.8, output
    assert float(found.group(1)) <= 0.5, output
    for topic in ("/diffbot/odom", "/diffbot/range", "/diffbot/imu"):
        seen = re.search(rf"{topic}: (\d+)", output)
        assert seen is not None and int(seen.group(1)) > 10, output
    assert (tmp_path / "path.svg").exists()
    return output


def test_sim_command_prints_the_url_first(probe_elf: Path) -> None:
    process = subprocess.Popen(
        [sys.executable, "-m", "hwbridge", "firmware", "sim", str(probe_elf), "--robot", "diffbot"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout is not None
        first = process.stdout.readline().strip()
        assert re.fullmatch(r"serial:///dev/pts/\d+", first), first
    finally:
        process.send_signal(signal.SIGINT)
        assert process.wait(15) in (0, 130)  # 130: Ctrl-C before the command's loop


@pytest.mark.parametrize("firmware", ["DiffDriveBase", "generated"])
def test_mega_pan_servo_on_serial2(runner: Path, firmware: str) -> None:
    """DiffDriveBase for a Mega, and the firmware generated from diffbot.yaml for it: the pan
    servo on Serial2 is the emulated Dynamixel bus; a goal from the graph moves it and
    joint_states reports it; odometry comes too."""
    from hwbridge.emulator.board import load_board
    from hwbridge.emulator.pins import PinWorld
    from hwbridge.graph import Graph, GraphConfig
    from hwbridge.robot.runtime import RobotRuntime
    from hwbridge.sketchgen import generated_elf
    from tests.netutil import wait_until

    try:
        if firmware == "generated":
            elf = generated_elf(ROBOT_FILE, "mega")
        else:
            elf = build_example("DiffDriveBase", "mega")
    except HwBridgeError as exc:
        pytest.skip(f"{firmware} does not build here: {str(exc).splitlines()[0]}")
    sim = SimAvr(elf, mcu="atmega2560")
    packets: list[bytes] = []
    sim.on_uart.append(lambda _uart, data: packets.append(data))
    graph: Graph | None = None
    runtime: RobotRuntime | None = None
    try:
        sim.start(hold=True)
        world = PinWorld(sim, load_board(str(ROBOT_FILE), "base")).attach()
        assert world.skipped == []
        sim.go()
        graph = Graph(GraphConfig.embedded([f"tcp/127.0.0.1:{free_port()}"]))
        robot = load_robot(ROBOT_FILE).with_links({"base": sim.url})
        runtime = RobotRuntime(robot, graph).start()
        view = graph.node("mega_test", namespace="/diffbot")
        seen: dict[str, Any] = {}
        view.subscriber("joint_states", "sensor_msgs/JointState", lambda m: seen.update(j=m))
        view.subscriber("odom", "nav_msgs/Odometry", lambda m: seen.update(o=m))
        goal = view.publisher("pan/goal_position", "std_msgs/Float64")

        def at_goal() -> bool:
            goal.publish({"data": 0.5})
            joints = seen.get("j")
            return joints is not None and abs(float(joints.position[0]) - 0.5) < 0.01

        assert wait_until(at_goal, 30, 0.1), (len(packets), seen.get("j"))
        assert "o" in seen
        assert packets  # the firmware's own packets on the bus
    finally:
        if runtime is not None:
            runtime.stop()
        if graph is not None:
            graph.close()
        sim.close()
