"""A robot for the gateway tests, in real processes.

``hwbridge emulate diffbot`` (Imu, Odometry, cmd_vel) plus a second board on a pty, run in the
test process (a native session with a ``reset`` std_srvs/Trigger service that logs on each call
and on demand), both brought up by ``hwbridge up ROBOT.yaml`` with ``--ros2`` or the robot file's
``ros: {ros1: true}``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import yaml

from hwbridge import msg
from tests.boards import PtyBoard, native_sketch
from tests.netutil import free_port, reap, stop_child, wait_until

ROOT = Path(__file__).resolve().parents[2]
DIFFBOT = ROOT / "hwbridge" / "emulator" / "robots" / "diffbot.yaml"
PEER = Path(__file__).with_name("ros2_peer.py")


def aux_events(board: PtyBoard, event: Any) -> None:
    """Answer reset calls (success, "done") and log a line for each."""
    from hwbridge.protocols.native import session as ns
    from hwbridge.protocols.native.control import LogLevel

    if isinstance(event, ns.ServiceRequest):
        reply = msg.encode(msg.new("std_srvs/TriggerResponse", success=True, message="done"))

        def answer(session: Any) -> object:
            session.log(LogLevel.INFO, "aux: reset called")
            return session.respond_service(event.channel, event.request_id, reply)

        board.pump.call(answer)


class Robot:
    """The processes of one gateway test module; :meth:`stop` ends every one of them."""

    def __init__(self, tmp: Path, env: dict[str, str]) -> None:
        self.tmp = tmp
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.env = {
            **os.environ,
            **env,
            "HWBRIDGE_ENDPOINT": self.endpoint,
            "HWBRIDGE_DOMAIN": "gw",
            "ROS_HOME": str(tmp / "roshome"),
            "ROS_LOG_DIR": str(tmp / "roslog"),
        }
        self.processes: list[tuple[subprocess.Popen[str], Path]] = []
        self.aux: PtyBoard | None = None
        self.up_log = tmp / "up.log"

    def start(
        self, name: str, argv: list[str], env: dict[str, str] | None = None
    ) -> subprocess.Popen[str]:
        log = self.tmp / f"{name}.log"
        process = subprocess.Popen(
            argv,
            env=env or self.env,
            stdout=subprocess.PIPE,
            stderr=log.open("w"),
            stdin=subprocess.DEVNULL,
            text=True,
        )
        self.processes.append((process, log))
        return process

    def hwbridge(self, name: str, *argv: str) -> subprocess.Popen[str]:
        return self.start(name, [sys.executable, "-m", "hwbridge", *argv])

    def up(self, *gateway_flags: str, ros: dict[str, Any] | None = None) -> None:
        """``hwbridge up`` on the test robot with these flags, and ``ros`` as its robot file's
        ``ros:`` section (none when None)."""
        emulator = self.hwbridge("emulate", "emulate", "diffbot", "--tcp", str(free_port()))
        assert emulator.stdout is not None
        url = emulator.stdout.readline().strip()
        assert url, (self.tmp / "emulate.log").read_text()
        aux_path = self.tmp / "aux"
        self.aux = PtyBoard(aux_path, native_sketch("aux"), "aux", aux_events).start()
        robot = yaml.safe_load(DIFFBOT.read_text())
        robot["robot"] = "gwbot"
        robot["boards"].append(
            {"name": "aux", "link": str(aux_path), "protocol": "native", "namespace": "/aux"}
        )
        if ros is not None:
            robot["ros"] = ros
        robot_file = self.tmp / "gwbot.yaml"
        robot_file.write_text(yaml.safe_dump(robot))
        self.hwbridge("up", "up", str(robot_file), "--link", f"base={url}", *gateway_flags)

    def log(self, name: str) -> str:
        path = self.tmp / f"{name}.log"
        return path.read_text() if path.exists() else ""

    def wait_log(self, name: str, text: str, timeout: float = 60) -> None:
        assert wait_until(lambda: text in self.log(name), timeout, step=0.1), self.log(name)

    def cli(self, *argv: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "hwbridge", *argv],
            env=self.env,
            capture_output=True,
            text=True,
            timeout=timeout,
            check=False,
        )

    def board_log(self, text: str) -> None:
        """The aux board logs ``text`` (WARN)."""
        from hwbridge.protocols.native.control import LogLevel

        assert self.aux is not None
        self.aux.pump.call(lambda session: session.log(LogLevel.WARN, text))

    def stop_process(self, process: subprocess.Popen[str]) -> None:
        stop_child(process)

    def stop(self) -> None:
        for process, _log in reversed(self.processes):
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        for process, _log in self.processes:
            reap(process)
        if self.aux is not None:
            self.aux.stop()


def odom_x(robot: Robot) -> float:
    import json

    done = robot.cli("topic", "echo", "/diffbot/odom", "-n", "1", "--json", "--timeout", "20")
    assert done.returncode == 0, done.stderr
    return float(json.loads(done.stdout.splitlines()[0])["pose"]["pose"]["position"]["x"])
