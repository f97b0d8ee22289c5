"""End to end through real processes and a pty: board <-> ``hwbridge connect`` <-> CLI tools.

The test process plays the board (a device-side protocol session on the master end of a pty);
``hwbridge connect`` runs in a subprocess and opens the pty's slave like a serial port; CLI
commands run in further subprocesses.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from hwbridge import msg
from hwbridge.bridge import BoardSpec
from hwbridge.links import open_link
from hwbridge.protocols.rosserial import REQUEST_TOPICS, RosserialDevice
from tests.boards import (
    PtyBoard,
    answer_services,
    chatter,
    native_chatter,
    native_sketch,
    rosserial_sketch,
    wait_for,
)
from tests.bridgeproc import BridgeProcess

VECTORS = json.loads(
    (Path(__file__).resolve().parents[2] / "protocols" / "vectors" / "rosserial.json").read_text()
)
FRAMES = {f["name"]: bytes.fromhex(f["hex"]) for f in VECTORS["frames"]}


@pytest.fixture
def board_path(tmp_path: Path) -> Path:
    return tmp_path / "ttyBOARD"


@pytest.fixture
def bridge(board_path: Path, tmp_path: Path) -> Iterator[BridgeProcess]:
    process = BridgeProcess(board_path, tmp_path, "e2e", "--namespace", "/rs", "--name", "uno")
    process.wait_ready()
    yield process
    code = process.stop()
    assert code == 0, process.output()


def test_rosserial_board_through_bridge_and_cli(board_path: Path, bridge: BridgeProcess) -> None:
    device = rosserial_sketch()
    board = PtyBoard(board_path, device).start()
    count = [0]
    board.every(0.05, chatter(count))
    try:
        echo = bridge.cli("topic", "echo", "/rs/chatter", "-n", "1", "--timeout", "30")
        assert echo.returncode == 0, echo.stderr + bridge.output()
        assert yaml.safe_load(echo.stdout.split("---")[0])["data"].startswith("hello ")

        pub = bridge.cli("topic", "pub", "/rs/led", "std_msgs/Bool", "{data: true}")
        assert pub.returncode == 0, pub.stderr
        assert wait_for(lambda: any(e.payload == b"\x01" for e in board.of_type("Received")))

        call = bridge.cli("service", "call", "/rs/reset")
        assert call.returncode == 0, call.stderr
        assert yaml.safe_load(call.stdout) == {"success": True, "message": "done"}

        assert bridge.cli("param", "set", "/rs/speed", "[3, 10]").returncode == 0
        board.pump.call(lambda d: d.request_param("speed", board_now()))
        assert wait_for(lambda: bool(board.of_type("ParamResult")))
        assert board.of_type("ParamResult")[0].ints == (3, 10)

        listing = bridge.cli("board", "list")
        assert listing.returncode == 0
        assert listing.stdout.split("\t")[0] == "uno"
        stats = bridge.cli("board", "stats", "uno", "--json")
        assert stats.returncode == 0, stats.stderr
        data = json.loads(stats.stdout)
        assert data["protocol"] == "rosserial"
        assert data["link"]["bytes_in"] > 0
    finally:
        board.stop()


def board_now() -> float:
    import time

    return time.monotonic()


def test_bridge_recovers_when_the_board_goes_and_comes_back(
    board_path: Path, bridge: BridgeProcess
) -> None:
    count = [0]
    first = PtyBoard(board_path, rosserial_sketch()).start()
    first.every(0.05, chatter(count))
    assert bridge.cli("topic", "echo", "/rs/chatter", "-n", "1", "--timeout", "30").returncode == 0
    first.stop()  # unplugged: the pty and its path disappear
    assert wait_for(lambda: "link lost" in bridge.output(), 15), bridge.output()
    gone = bridge.cli("topic", "list")
    assert "/rs/chatter" not in gone.stdout.split()

    second = PtyBoard(board_path, rosserial_sketch()).start()  # plugged in again, same path
    second.every(0.05, chatter(count))
    try:
        again = bridge.cli("topic", "echo", "/rs/chatter", "-n", "1", "--timeout", "30")
        assert again.returncode == 0, again.stderr + bridge.output()
        assert "board connected" in bridge.output()
        stats = json.loads(bridge.cli("board", "info", "uno", "--json").stdout)
        assert stats["connects"] >= 2
    finally:
        second.stop()


def test_golden_vector_frames_reach_the_graph(board_path: Path, bridge: BridgeProcess) -> None:
    """A raw 'board' that answers with the exact frames of protocols/vectors/rosserial.json."""
    link = open_link(f"pty://?symlink={board_path}")
    stop = threading.Event()

    def play() -> None:
        buffered = b""
        while not stop.is_set():
            buffered += link.read(4096, timeout=0.05)
            if REQUEST_TOPICS in buffered:
                buffered = b""
                link.write(FRAMES["time_request"] + FRAMES["topic_info_publisher_chatter"])
            if len(buffered) > 4096:
                buffered = buffered[-64:]
            try:
                link.write(FRAMES["message_chatter"])
            except Exception:  # noqa: BLE001 - nobody attached yet
                continue

    thread = threading.Thread(target=play, daemon=True)
    thread.start()
    try:
        echo = bridge.cli("topic", "echo", "/rs/chatter", "-n", "1", "--timeout", "30")
        assert echo.returncode == 0, echo.stderr + bridge.output()
        assert yaml.safe_load(echo.stdout.split("---")[0]) == {"data": "hello world!"}
    finally:
        stop.set()
        thread.join(5)
        link.close()


def test_native_board_through_bridge_and_cli_with_reset(
    board_path: Path, bridge: BridgeProcess
) -> None:
    count = [0]
    board = PtyBoard(board_path, native_sketch(), on_event=answer_services).start()
    board.every(0.05, native_chatter(count))
    try:
        echo = bridge.cli("topic", "echo", "/rs/chatter", "-n", "1", "--timeout", "30")
        assert echo.returncode == 0, echo.stderr + bridge.output()
        assert "speaks native" in bridge.output()
        pub = bridge.cli("topic", "pub", "/rs/led", "std_msgs/Bool", "{data: true}")
        assert pub.returncode == 0, pub.stderr
        assert wait_for(lambda: any(e.payload == b"\x01" for e in board.of_type("Message")))
        call = bridge.cli("service", "call", "/rs/reset")
        assert call.returncode == 0, call.stderr
        assert yaml.safe_load(call.stdout) == {"success": True, "message": "done"}
        stats = json.loads(bridge.cli("board", "stats", "uno", "--json").stdout)
        assert stats["protocol"] == "native"
        assert stats["stats"]["crc_errors"] == 0
        assert stats["stats"]["be_messages_received"] > 0
    finally:
        board.stop()
    # The board resets: a new device session (new session id) on the same port.
    again = PtyBoard(board_path, native_sketch())
    again.start()
    again.every(0.05, native_chatter(count))
    try:
        echo = bridge.cli("topic", "echo", "/rs/chatter", "-n", "1", "--timeout", "30")
        assert echo.returncode == 0, echo.stderr + bridge.output()
        assert bridge.output().count("connected (native)") >= 2
    finally:
        again.stop()


@pytest.mark.parametrize(
    ("url", "name"),
    [
        ("/dev/ttyACM0", "ttyACM0"),
        ("serial:///dev/ttyUSB0?baud=115200", "ttyUSB0"),
        ("tcp-listen://:11411", "board_11411"),
        ("socket://192.168.4.1:2323", "board_192_168_4_1_2323"),
        ("pty://", "pty"),
    ],
)
def test_a_board_is_named_after_its_url(url: str, name: str) -> None:
    assert BoardSpec(url).name == name


ODD_MD5 = "0123456789abcdef0123456789abcdef"


def test_rosserial_arduino_test_service_and_an_unknown_type_work_from_the_cli(
    board_path: Path, bridge: BridgeProcess
) -> None:
    """Issue 12's rosserial completeness: a rosserial_arduino/Test server (a type from
    rosserial_arduino) and a publisher of a type the host has never heard of both appear on the
    graph; the service is called from the CLI and the unknown topic is echoed as raw bytes."""
    device = RosserialDevice(msg.registry())
    device.advertise("odd", "acme_msgs/Odd", ODD_MD5)

    def shout(request: bytes) -> bytes:
        text = msg.decode(request, "rosserial_arduino/TestRequest").input
        return msg.encode(msg.new("rosserial_arduino/TestResponse", output=text.upper()))

    device.advertise_service("test_srv", "rosserial_arduino/Test", shout)
    board = PtyBoard(board_path, device).start()
    board.every(0.05, lambda d: d.publish("odd", b"\x01\x02\xff"))
    try:
        assert wait_for(lambda: "/rs/test_srv" in bridge.cli("service", "list").stdout, 30), (
            bridge.output()
        )
        call = bridge.cli("service", "call", "/rs/test_srv", "{input: hello}", "--json")
        assert call.returncode == 0, call.stderr + bridge.output()
        assert json.loads(call.stdout) == {"output": "HELLO"}

        echo = bridge.cli("topic", "echo", "/rs/odd", "-n", "1", "--json", "--timeout", "30")
        assert echo.returncode == 0, echo.stderr + bridge.output()
        shown = json.loads(echo.stdout.splitlines()[0])
        assert shown == {"type": "acme_msgs/Odd", "md5": ODD_MD5, "raw": "0102ff"}
        assert "no definition of acme_msgs/Odd" in echo.stderr
        listing = bridge.cli("topic", "list", "-v")
        assert "acme_msgs/Odd" in listing.stdout
        assert bridge.output().count("acme_msgs/Odd") >= 1  # the bridge said it passes it raw
    finally:
        board.stop()
