"""The board side of CAN (``firmware/HwBridge/src/hwbridge/can/``).

- The C++ transport against ``protocols/vectors/can_frames.json`` and ``can_frames_v2.json``
  and ``CanHardware`` with a scripted driver, plain and under ASan/UBSan with -Wall -Wextra
  -Werror; a seeded, time-bounded fuzz of the C++ receiver; the MCP2515 driver against a
  register-level fake of the chip (SPI transactions) (``firmware/tests/can/``).
- End to end: ``firmware/tests/can/CanE2E`` built as a host program runs as CAN node 5 through
  the host-native driver and a relay (:mod:`tests.firmware.can_relay`) onto a python-can
  ``udp_multicast`` bus; ``hwbridge connect can://udp_multicast/.../node5`` (a process of its
  own) bridges it and an emulated board (node 2, ``hwbridge.emulator.can_bus``) on the same bus:
  a topic each way, a service and a parameter work on the sketch, and the emulated board's
  service and topic keep working, its session never renegotiated; the sketch restarted is
  taken back. The same with one side of CAN.md version 1 (``HWBRIDGE_CAN_FORMAT=1`` for the
  sketch, ``can_format=1`` for the bridge): both boards connect and answer. The sketch's
  best-effort ``sensor_msgs/Imu`` (six native fragments) arrives intact through the bridge, as
  chained transfers (CAN.md §12) to a version-3 host, and as one transfer per fragment when
  either end is version 2 (``HWBRIDGE_CAN_CHAINS=0``, ``can_chain=0``).

``examples/CanNode`` (the MCP2515 driver and ``CanHardware`` on an AVR) is built for the Uno and
the Mega by both tools in ``test_examples.py`` like every example.
"""

from __future__ import annotations

import random
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from tests.bridgeproc import BridgeProcess, new_sessions
from tests.netutil import free_port, wait_until

ROOT = Path(__file__).resolve().parents[2]
CAN_TESTS = ROOT / "firmware" / "tests" / "can"
INCLUDE = ROOT / "firmware" / "HwBridge" / "src"
FLAGS = ["-std=c++11", "-Wall", "-Wextra", "-Werror", "-O1", f"-I{INCLUDE}"]
SANITIZE = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-O0"]
"""At -O0 as in tests/firmware/test_cpp_core.py (half the build time); the plain build is -O1."""

needs_gpp = pytest.mark.skipif(
    shutil.which("g++") is None, reason="g++ is not installed (Debian package g++)"
)


def _build(name: str, out: Path, sanitize: bool) -> Path:
    exe = out / (name + ("_san" if sanitize else ""))
    command = ["g++", *FLAGS, *(SANITIZE if sanitize else []), str(CAN_TESTS / f"{name}.cpp")]
    done = subprocess.run([*command, "-o", str(exe)], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    return exe


def _vector_lines() -> str:
    done = subprocess.run(
        ["python3", str(CAN_TESTS / "can_vectors.py")], capture_output=True, text=True, check=True
    )
    return done.stdout


@needs_gpp
@pytest.mark.parametrize("sanitize", [False, True], ids=["plain", "asan"])
def test_transport_vectors_and_can_hardware(tmp_path: Path, sanitize: bool) -> None:
    exe = _build("test_can_vectors", tmp_path, sanitize)
    lines = _vector_lines()
    assert lines.count("\nbad ") >= 10
    done = subprocess.run([str(exe)], input=lines, capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    assert "checks passed" in done.stdout


@needs_gpp
def test_transport_vectors_can_fail(tmp_path: Path) -> None:
    """A vector changed by one bit fails the C++ check."""
    exe = _build("test_can_vectors", tmp_path, False)
    lines = _vector_lines().replace("01020304050607e1", "01020304050607e2", 1)
    done = subprocess.run([str(exe)], input=lines, capture_output=True, text=True, check=False)
    assert done.returncode == 1 and "check failed" in done.stderr


@needs_gpp
@pytest.mark.parametrize("sanitize", [False, True], ids=["plain", "asan"])
def test_mcp2515_against_a_register_level_fake(tmp_path: Path, sanitize: bool) -> None:
    exe = _build("test_mcp2515", tmp_path, sanitize)
    done = subprocess.run([str(exe)], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    assert "checks passed" in done.stdout


@needs_gpp
def test_receiver_fuzz(tmp_path: Path) -> None:
    exe = _build("fuzz_can_receiver", tmp_path, True)
    seed = random.Random().randrange(1, 1 << 31)
    done = subprocess.run([str(exe), str(seed), "2"], capture_output=True, text=True, check=False)
    assert done.returncode == 0, f"seed {seed}: {done.stderr}"
    assert "transfers delivered" in done.stdout


# ----------------------------------------------------------------------------- end to end

NODE = 5
OTHER = 2


@pytest.fixture(scope="module")
def program(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if shutil.which("g++") is None:
        pytest.skip("g++ is not installed (Debian package g++)")
    from hwbridge.firmware.build import build_host_sketch

    return build_host_sketch(CAN_TESTS / "CanE2E", tmp_path_factory.mktemp("can_e2e"))


class Bus:
    """A udp_multicast group of its own, with the relay of the board program and one emulated
    board on it."""

    def __init__(self) -> None:
        import can

        from hwbridge.emulator.can_bus import CanBusEmulator
        from tests.firmware.can_relay import CanRelay

        self.group = f"239.74.{random.randrange(1, 250)}.{random.randrange(1, 250)}"
        self.port = free_port()
        self.relay_bus = can.Bus(interface="udp_multicast", channel=self.group, port=self.port)
        self.relay = CanRelay(self.relay_bus, NODE)
        self.emulator = CanBusEmulator(
            lambda: can.Bus(interface="udp_multicast", channel=self.group, port=self.port),
            1,
            first=OTHER,
            rate=5.0,
            sensor_rate=0.5,
            pace=125000,
        ).start()

    def url(self, node: int) -> str:
        return f"can://udp_multicast/{self.group}/node{node}?port={self.port}"

    def close(self) -> None:
        self.emulator.stop()
        self.relay.close()
        self.relay_bus.shutdown()


@pytest.fixture
def bus() -> Iterator[Bus]:
    b = Bus()
    yield b
    b.close()


def _values(out: str) -> list[int]:
    docs = [yaml.safe_load(d) for d in out.split("---") if d.strip()]
    return [int(d["data"]) for d in docs]


@needs_gpp
def test_host_sketch_on_a_can_bus_with_an_emulated_board(
    program: Path, bus: Bus, tmp_path: Path
) -> None:
    bridge = BridgeProcess(bus.url(NODE), tmp_path, f"canfw{free_port()}", bus.url(OTHER))
    board: subprocess.Popen[bytes] | None = None
    log = (tmp_path / "board.log").open("w")
    try:
        bridge.wait_ready()
        assert bridge.cli("param", "set", "/rate", "9").returncode == 0
        env = {"HWBRIDGE_CAN": f"127.0.0.1:{bus.relay.port}", "HWBRIDGE_CAN_NODE": str(NODE)}
        board = subprocess.Popen(
            [str(program)], env={**bridge.env, **env}, stdout=log, stderr=subprocess.STDOUT
        )
        assert wait_until(lambda: "board 'canboard' connected" in bridge.output(), 30), (
            bridge.output()
        )
        assert wait_until(lambda: "board 'node2' connected" in bridge.output(), 30), bridge.output()
        topics = bridge.cli("topic", "list").stdout
        counter = next(t for t in topics.split() if t.endswith("counter"))
        echo = bridge.cli("topic", "echo", counter, "-n", "5", "--timeout", "30")
        assert echo.returncode == 0, echo.stderr + bridge.output()
        counts = _values(echo.stdout)
        assert counts == list(range(counts[0], counts[0] + 5))

        services = bridge.cli("service", "list").stdout
        ping = next(s for s in services.split() if s.endswith("ping"))
        call = bridge.cli("service", "call", ping)
        assert call.returncode == 0, call.stderr + bridge.output()
        assert yaml.safe_load(call.stdout) == {"success": True, "message": "pong 1"}

        assert wait_until(lambda: "rate is 9" in bridge.output(), 10), bridge.output()
        cmd = next(t for t in topics.split() if t.endswith("cmd"))
        pub = bridge.cli("topic", "pub", cmd, "std_msgs/String", "{data: over-can}")
        assert pub.returncode == 0, pub.stderr
        assert wait_until(lambda: "got over-can" in bridge.output(), 10), bridge.output()

        # the emulated board on the same bus: its service and topic work, its session is the one
        # it started with
        who = bridge.cli("service", "call", f"/node{OTHER}/whoami")
        assert who.returncode == 0, who.stderr + bridge.output()
        assert yaml.safe_load(who.stdout) == {"success": True, "message": f"node {OTHER}"}
        count = bridge.cli("topic", "echo", f"/node{OTHER}/count", "-n", "2", "--timeout", "30")
        assert count.returncode == 0, count.stderr
        output = bridge.output()
        assert new_sessions(output, "node2") == 1, output
        assert new_sessions(output, "canboard") == 1, output
        assert bus.relay.to_bus > 0 and bus.relay.from_bus > 0

        # the board restarts (new session, transfer ids from 0 again): the bridge takes it back
        board.kill()
        board.wait(10)
        board = subprocess.Popen(
            [str(program)], env={**bridge.env, **env}, stdout=log, stderr=subprocess.STDOUT
        )
        assert wait_until(lambda: new_sessions(bridge.output(), "canboard") >= 2, 30), (
            bridge.output()
        )
        call = bridge.cli("service", "call", ping)
        assert yaml.safe_load(call.stdout) == {"success": True, "message": "pong 1"}, call.stderr
        assert new_sessions(bridge.output(), "node2") == 1, bridge.output()
    finally:
        if board is not None:
            board.kill()
            board.wait(10)
        bridge.stop()
        log.close()


@needs_gpp
@pytest.mark.parametrize("old", ["board", "host"])
def test_version_1_and_version_2_nodes_on_one_bus(
    program: Path, bus: Bus, tmp_path: Path, old: str
) -> None:
    """CAN.md version 1 meets version 2 (CAN.md §11): the sketch as version-1 firmware
    (HWBRIDGE_CAN_FORMAT=1) under a format-2 host, which says so and speaks format 1 to it; or
    the sketch as format-2 firmware under a version-1 host (``can_format=1``, which drops
    format-2 frames as malformed), whose claims turn the sketch and the emulated board to
    format 1. Either way both boards connect and answer."""
    query = "&can_format=1" if old == "host" else ""
    bridge = BridgeProcess(
        bus.url(NODE) + query, tmp_path, f"canv{free_port()}", bus.url(OTHER) + query
    )
    board: subprocess.Popen[bytes] | None = None
    log = (tmp_path / "board.log").open("w")
    try:
        bridge.wait_ready()
        env = {"HWBRIDGE_CAN": f"127.0.0.1:{bus.relay.port}", "HWBRIDGE_CAN_NODE": str(NODE)}
        if old == "board":
            env["HWBRIDGE_CAN_FORMAT"] = "1"
        board = subprocess.Popen(
            [str(program)], env={**bridge.env, **env}, stdout=log, stderr=subprocess.STDOUT
        )
        assert wait_until(lambda: "board 'canboard' connected" in bridge.output(), 30), (
            bridge.output()
        )
        assert wait_until(lambda: "board 'node2' connected" in bridge.output(), 30), bridge.output()
        services = bridge.cli("service", "list").stdout
        ping = next(s for s in services.split() if s.endswith("ping"))
        call = bridge.cli("service", "call", ping)
        assert call.returncode == 0, call.stderr + bridge.output()
        assert yaml.safe_load(call.stdout) == {"success": True, "message": "pong 1"}
        who = bridge.cli("service", "call", f"/node{OTHER}/whoami")
        assert who.returncode == 0, who.stderr + bridge.output()
        output = bridge.output()
        if old == "board":
            assert f"node {NODE} claims in CAN.md format 1 (older firmware)" in output, output
            assert f"node {OTHER} claims in CAN.md format 1" not in output, output
        else:
            assert "claims in CAN.md format" not in output, output
    finally:
        if board is not None:
            board.kill()
            board.wait(10)
        bridge.stop()
        log.close()


@needs_gpp
@pytest.mark.parametrize("version_2", ["none", "board", "host"])
def test_chained_imu_through_the_bridge(
    program: Path, bus: Bus, tmp_path: Path, version_2: str
) -> None:
    """The sketch publishes a 320-byte sensor_msgs/Imu best effort at the native MTU of 64: to a
    version-3 host its six fragments go as one chained transfer (46 frames, Cyphal/CAN's count),
    and the bridge delivers the message whole; with either end as version 2 they go as six
    transfers, and the message still arrives."""
    query = "&can_chain=0" if version_2 == "host" else ""
    bridge = BridgeProcess(bus.url(NODE) + query, tmp_path, f"canc{free_port()}")
    board: subprocess.Popen[bytes] | None = None
    log = (tmp_path / "board.log").open("w")
    try:
        bridge.wait_ready()
        env = {"HWBRIDGE_CAN": f"127.0.0.1:{bus.relay.port}", "HWBRIDGE_CAN_NODE": str(NODE)}
        if version_2 == "board":
            env["HWBRIDGE_CAN_CHAINS"] = "0"
        board = subprocess.Popen(
            [str(program)], env={**bridge.env, **env}, stdout=log, stderr=subprocess.STDOUT
        )
        assert wait_until(lambda: "board 'canboard' connected" in bridge.output(), 30), (
            bridge.output()
        )
        topics = bridge.cli("topic", "list").stdout
        imu = next(t for t in topics.split() if t.endswith("/imu"))
        echo = bridge.cli("topic", "echo", imu, "-n", "4", "--timeout", "30")
        assert echo.returncode == 0, echo.stderr + bridge.output()
        docs = [yaml.safe_load(d) for d in echo.stdout.split("---") if d.strip()]
        assert len(docs) == 4
        for doc in docs:
            assert doc["header"]["frame_id"] == "imu_link"
            assert doc["linear_acceleration"]["z"] == pytest.approx(9.81)
        counts = [d["orientation"]["w"] for d in docs]
        assert counts == sorted(counts) and len(set(counts)) == 4, counts
        if version_2 == "none":
            assert bus.relay.chained_to_bus >= 4 * 46, bus.relay.chained_to_bus
        else:
            assert bus.relay.chained_to_bus == 0
    finally:
        if board is not None:
            board.kill()
            board.wait(10)
        bridge.stop()
        log.close()
