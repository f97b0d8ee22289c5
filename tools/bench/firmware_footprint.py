"""Firmware footprint on the ATmega328P: hwbridge's HwBridge library next to rosserial's ros_lib.

Each sketch is built for the Uno by ``hwbridge firmware build``'s own code (gcc-avr, the Debian
Arduino core, ``-Os -flto``, sections garbage-collected) and measured by ``hwbridge firmware
size`` (avr-size: flash = .text + .data, SRAM = .data + .bss). The cases:

* ``empty``: ``setup() {}`` / ``loop() {}``, and ``serial``: ``Serial.begin(57600)`` alone (the
  Arduino core's share of every node; the issue's "empty sketch", 1452 B / 184 B);
* ``hello_world``: hwbridge's ``examples/HelloWorld`` and rosserial's HelloWorld (a String
  publisher);
* ``pub_sub_service``: a String publisher, an Empty subscriber and a
  ``rosserial_arduino/Test`` service server, written alike for both libraries.

rosserial is built the same way in the same run from a checkout of
https://github.com/ros-drivers/rosserial (branch ``noetic-devel``) given by ``--rosserial DIR``
or ``ROSSERIAL_DIR`` (a work tree, or a bare git directory whose ``noetic-devel`` or ``HEAD`` is
exported). Its ros_lib is assembled as rosserial's ``make_libraries`` would (``rosserial_client``'s
core, ``rosserial_arduino``'s ``ros.h`` and ``ArduinoHardware.h``); the message headers it needs
(std_msgs String, Time, Empty; rosserial_msgs TopicInfo, Log, RequestParam;
rosserial_arduino Test) are generated at bench time by rosserial's own
``make_library.py`` (its message classes; the ROS lookups it imports are not needed) from
rosserial's ``.msg``/``.srv`` files and std_msgs' definitions, with md5 sums from hwbridge's
type registry. Nothing of rosserial is copied into this repository. Without the checkout the
bench prints how to get it and exits 0.

The same hello world and pub/sub/service sketches are built for the two ARM boards of
``hwbridge firmware build`` (``stm32f405``: Cortex-M4F; ``microbit``: nRF51822, Cortex-M0;
arm-none-eabi-gcc, newlib-nano, ``-Os``, sections garbage-collected, no LTO) and measured with
arm-none-eabi-size (flash = .text + .data, RAM = .data + .bss): one line per board and case
(``"board": ...``), with the Uno's figures of the same run beside them (``avr_flash``,
``avr_sram``) and the ARM build of an empty sketch (``empty``: the start-up, the Arduino
stand-in and newlib's share). Without the ARM toolchain those lines are skipped with a line
saying so.

micro-ROS is not built here; its line (``"peer": "micro-ROS"``) gives its published memory
figures, from the micro-ROS benchmarking page of eProsima's documentation (Vulcanexus, "micro-ROS
Benchmarking", Memory Profiling: measured on a Renesas EK-RA6M5, UDP transport, MTU 512 B,
history 4): about 550 B per publisher, 600 B per subscriber, 500 B per service server, and the
RMW history's static pools of MTU x history = 2048 B, on top of the XRCE-DDS session, the
transport and the RTOS (not counted there). ``floor_pub_sub_service_ram`` adds the three entities
and one history pool: a lower bound for the pub/sub/service case, compared with hwbridge's whole
static RAM for that case on each ARM board.

Output: one JSON line per case, e.g. ``{"bench": "firmware_footprint", "case":
"hello_world", "hwbridge_flash": ..., "hwbridge_sram": ..., "peer": "rosserial",
"peer_flash": ..., "peer_sram": ..., "flash_ratio": ..., "sram_ratio": ...}`` (ratio =
hwbridge / rosserial), with the issue's reference figures for rosserial and its floors for
hwbridge (``floor_flash``, ``floor_sram``, ``within_floor``), and PROTOCOL.md 2.13's predicted
hello-world RAM.

    git clone -b noetic-devel https://github.com/ros-drivers/rosserial /tmp/rosserial
    ROSSERIAL_DIR=/tmp/rosserial .venv/bin/python tools/bench/firmware_footprint.py
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
import types
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from hwbridge import msg  # noqa: E402
from hwbridge.errors import HwBridgeError  # noqa: E402
from hwbridge.firmware.build import (  # noqa: E402
    ARM_BOARDS,
    LIBRARY_DIR,
    arm_firmware_size,
    build_sketch,
    firmware_size,
)

BENCH = "firmware_footprint"
HOW_TO_GET = (
    "rosserial is not available: git clone -b noetic-devel "
    "https://github.com/ros-drivers/rosserial DIR, then pass --rosserial DIR or set "
    "ROSSERIAL_DIR=DIR"
)
# The figures for rosserial measured earlier, and its floors for hwbridge.
REFERENCE = {
    "hello_world": {"reference_peer_flash": 9236, "reference_peer_sram": 1362},
    "pub_sub_service": {"reference_peer_flash": 10986, "reference_peer_sram": 1764},
    "serial": {"reference_flash": 1452, "reference_sram": 184},
}
FLOORS = {"hello_world": (7290, 700), "pub_sub_service": (None, 1000)}
PROTOCOL_PREDICTED_HELLO_SRAM = 657  # PROTOCOL.md 2.13
# micro-ROS's published memory figures (see the module docstring for the source).
MICRO_ROS = {
    "publisher_ram": 550,
    "subscriber_ram": 600,
    "service_ram": 500,
    "rmw_history_static_ram": 2048,
    "source": "micro-ROS benchmarking, Vulcanexus docs (EK-RA6M5, UDP, MTU 512, history 4)",
}

STD_MSGS = {"String": ["string data"], "Time": ["time data"], "Empty": []}

ROS_HELLO = """\
#include <ros.h>
#include <std_msgs/String.h>

ros::NodeHandle nh;
std_msgs::String str_msg;
ros::Publisher chatter("chatter", &str_msg);
char hello[13] = "hello world!";

void setup() {
  nh.initNode();
  nh.advertise(chatter);
}

void loop() {
  str_msg.data = hello;
  chatter.publish(&str_msg);
  nh.spinOnce();
  delay(1000);
}
"""

ROS_PUB_SUB_SERVICE = """\
#include <ros.h>
#include <std_msgs/String.h>
#include <std_msgs/Empty.h>
#include <rosserial_arduino/Test.h>

ros::NodeHandle nh;
std_msgs::String str_msg;
ros::Publisher chatter("chatter", &str_msg);

void toggle(const std_msgs::Empty&) { digitalWrite(13, !digitalRead(13)); }
ros::Subscriber<std_msgs::Empty> sub("toggle_led", &toggle);

void serve(const rosserial_arduino::Test::Request& req, rosserial_arduino::Test::Response& res) {
  res.output = req.input;
}
ros::ServiceServer<rosserial_arduino::Test::Request, rosserial_arduino::Test::Response>
    server("test_srv", &serve);

void setup() {
  pinMode(13, OUTPUT);
  nh.initNode();
  nh.advertise(chatter);
  nh.subscribe(sub);
  nh.advertiseService(server);
}

void loop() {
  str_msg.data = "hello world!";
  chatter.publish(&str_msg);
  nh.spinOnce();
  delay(1000);
}
"""

HWBRIDGE_PUB_SUB_SERVICE = """\
#include <HwBridge.h>
#include <std_msgs/String.h>
#include <std_msgs/Empty.h>
#include <rosserial_arduino/Test.h>

hwbridge::NodeHandle nh;
std_msgs::String str_msg;
hwbridge::Publisher<std_msgs::String> chatter("chatter");

void toggle(const std_msgs::Empty&) { digitalWrite(13, !digitalRead(13)); }
hwbridge::Subscriber<std_msgs::Empty> sub("toggle_led", &toggle);

void serve(const rosserial_arduino::Test::Request& req, rosserial_arduino::Test::Response& res) {
  res.output.assign(req.input.c_str());
}
hwbridge::ServiceServer<rosserial_arduino::Test> server("test_srv", &serve);

unsigned long last_ms = 0;

void setup() {
  pinMode(13, OUTPUT);
  nh.initNode(115200, "bench");
  nh.advertise(chatter);
  nh.subscribe(sub);
  nh.advertiseService(server);
  str_msg.data.assign("hello world!");
}

void loop() {
  if (millis() - last_ms >= 1000) {
    last_ms = millis();
    chatter.publish(str_msg);
  }
  nh.spinOnce();
}
"""

EMPTY = "void setup() {}\nvoid loop() {}\n"
SERIAL = "void setup() { Serial.begin(57600); }\nvoid loop() {}\n"


def _sketch(folder: Path, name: str, text: str) -> Path:
    sketch = folder / name
    sketch.mkdir(parents=True, exist_ok=True)
    (sketch / f"{name}.ino").write_text(text, encoding="utf-8")
    return sketch


def _rosserial_tree(location: Path, work: Path) -> Path:
    """A rosserial work tree: ``location`` itself, or exported from a bare git directory."""
    if (location / "rosserial_client" / "src" / "ros_lib").is_dir():
        return location
    tree = work / "rosserial"
    tree.mkdir()
    for ref in ("noetic-devel", "HEAD"):
        archive = subprocess.run(
            ["git", f"--git-dir={location}", "archive", ref],
            capture_output=True,
            check=False,
        )
        if archive.returncode == 0:
            subprocess.run(["tar", "-x", "-C", str(tree)], input=archive.stdout, check=True)
            return tree
    raise HwBridgeError(f"{location}: neither a rosserial checkout nor a git directory of one")


def _make_library_module(tree: Path) -> Any:
    """rosserial's make_library.py, loaded with empty stand-ins for the ROS modules it imports
    (only its message classes are used: they need none)."""
    for name in ("roslib", "roslib.srvs", "roslib.message"):
        sys.modules.setdefault(name, types.ModuleType(name))
    path = tree / "rosserial_client" / "src" / "rosserial_client" / "make_library.py"
    spec = importlib.util.spec_from_file_location("rosserial_make_library", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    # The Arduino type table, as rosserial_arduino's make_libraries.py sets it (evaluated from
    # that file: float64 as a 4-byte float, time as ros::Time, ...).
    script = tree / "rosserial_arduino" / "src" / "rosserial_arduino" / "make_libraries.py"
    for node in ast.parse(script.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "ROS_TO_EMBEDDED_TYPES" for t in node.targets
        ):
            table = eval(compile(ast.Expression(node.value), str(script), "eval"), vars(module))
            vars(module)["ROS_TO_EMBEDDED_TYPES"] = table
            return module
    raise HwBridgeError(f"{script}: no ROS_TO_EMBEDDED_TYPES")


def _definition(path: Path) -> list[str]:
    return path.read_text(encoding="utf-8").splitlines()


def _md5(type_name: str, fallback: str) -> str:
    try:
        return msg.md5(type_name)
    except Exception:  # noqa: BLE001 - a type the registry does not have
        return msg.md5(fallback)


def build_ros_lib(tree: Path, out: Path) -> Path:
    """ros_lib as an Arduino library folder (``out/src``), headers generated by rosserial."""
    src = out / "src"
    shutil.copytree(tree / "rosserial_client" / "src" / "ros_lib", src)
    shutil.rmtree(src / "tf", ignore_errors=True)
    for name in ("ros.h", "ArduinoHardware.h"):
        shutil.copy(tree / "rosserial_arduino" / "src" / "ros_lib" / name, src / name)
    generator = _make_library_module(tree)

    def write(package: str, name: str, thing: Any) -> None:
        (src / package).mkdir(exist_ok=True)
        text = io.StringIO()
        thing.make_header(text)
        (src / package / f"{name}.h").write_text(text.getvalue(), encoding="utf-8")

    for name, lines in STD_MSGS.items():
        write(
            "std_msgs",
            name,
            generator.Message(name, "std_msgs", lines, msg.md5(f"std_msgs/{name}")),
        )
    msgs = tree / "rosserial_msgs"
    for name in ("TopicInfo", "Log"):
        definition = _definition(msgs / "msg" / f"{name}.msg")
        md5 = msg.md5(f"rosserial_msgs/{name}")
        write("rosserial_msgs", name, generator.Message(name, "rosserial_msgs", definition, md5))
    for package, name, folder in (
        ("rosserial_msgs", "RequestParam", msgs),
        ("rosserial_arduino", "Test", tree / "rosserial_arduino"),
    ):
        definition = _definition(folder / "srv" / f"{name}.srv")
        service = f"{package}/{name}"
        request = _md5(f"{service}Request", "std_msgs/String")
        response = _md5(f"{service}Response", "std_msgs/String")
        write(package, name, generator.Service(name, package, definition, request, response))
    # Third-party code under `hwbridge firmware build`'s -Wall -Wextra -Werror: its headers are
    # marked as system headers (as if installed), so their warnings (unused parameters of
    # std_msgs/Empty's serializers) do not stop the build. The code is unchanged.
    for header in src.rglob("*.h"):
        header.write_text("#pragma GCC system_header\n" + header.read_text(encoding="utf-8"))
    return out


def _size(sketch: Path, out: Path, libraries: list[Path] | None = None) -> dict[str, Any]:
    elf = build_sketch(sketch, "uno", out, libraries=libraries)
    return firmware_size(elf).as_dict()


def _ratio(a: int, b: int) -> float:
    return round(a / b, 3) if b else 0.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n", 1)[0])
    parser.add_argument("--rosserial", type=Path, default=os.environ.get("ROSSERIAL_DIR"))
    parser.add_argument("--keep", type=Path, help="build here and keep it (default: a temp dir)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="hwbridge-footprint-") as temp:
        work = args.keep or Path(temp)
        work.mkdir(parents=True, exist_ok=True)
        lines: list[dict[str, Any]] = []
        for case, text in (("empty", EMPTY), ("serial", SERIAL)):
            size = _size(_sketch(work / "plain", case, text), work / "build" / case, [])
            lines.append(
                {"bench": BENCH, "case": case, "flash": size["flash"], "sram": size["sram"]}
                | REFERENCE.get(case, {})
            )
        # hwbridge: its HelloWorld example; the pub/sub/service sketch with the Test service
        # generated by hwbridge into the sketch's folder (which is on the include path).
        ours: dict[str, dict[str, Any]] = {}
        ours["hello_world"] = _size(
            LIBRARY_DIR / "examples" / "HelloWorld", work / "build" / "hw_hello"
        )
        pss = _sketch(work / "hwbridge", "PubSubService", HWBRIDGE_PUB_SUB_SERVICE)
        subprocess.run(
            [
                sys.executable,
                "-m",
                "hwbridge",
                "firmware",
                "generate",
                str(pss),
                "rosserial_arduino/Test",
            ],
            check=True,
            capture_output=True,
        )
        ours["pub_sub_service"] = _size(pss, work / "build" / "hw_pss")
        theirs: dict[str, dict[str, Any]] = {}
        if args.rosserial is None or not Path(args.rosserial).exists():
            sys.stderr.write(HOW_TO_GET + "\n")
        else:
            tree = _rosserial_tree(Path(args.rosserial), work)
            ros_lib = build_ros_lib(tree, work / "ros_lib")
            for case, text in (
                ("hello_world", ROS_HELLO),
                ("pub_sub_service", ROS_PUB_SUB_SERVICE),
            ):
                sketch = _sketch(work / "rosserial_sketches", f"ros_{case}", text)
                theirs[case] = _size(sketch, work / "build" / f"ros_{case}", [ros_lib])
        for case, size in ours.items():
            line: dict[str, Any] = {
                "bench": BENCH,
                "case": case,
                "hwbridge_flash": size["flash"],
                "hwbridge_sram": size["sram"],
                "hwbridge_library_sram": size["library_sram"],
                # the sketch's globals: its NodeHandle, publishers and messages (library types)
                "hwbridge_sketch_sram": size["sketch_sram"],
                "core_sram": size["core_sram"],
            }
            peer = theirs.get(case)
            if peer is not None:
                line |= {
                    "peer": "rosserial",
                    "peer_flash": peer["flash"],
                    "peer_sram": peer["sram"],
                    "flash_ratio": _ratio(size["flash"], peer["flash"]),
                    "sram_ratio": _ratio(size["sram"], peer["sram"]),
                }
            line |= REFERENCE.get(case, {})
            floor_flash, floor_sram = FLOORS[case]
            line |= {"floor_flash": floor_flash, "floor_sram": floor_sram}
            line["within_floor"] = size["sram"] <= floor_sram and (
                floor_flash is None or size["flash"] <= floor_flash
            )
            if case == "hello_world":
                line["protocol_predicted_sram"] = PROTOCOL_PREDICTED_HELLO_SRAM
            lines.append(line)
        lines.extend(_arm_lines(work, pss, ours))
        for line in lines:
            sys.stdout.write(json.dumps(line) + "\n")
    return 0


def _arm_lines(work: Path, pss: Path, avr: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """The ARM boards' lines, and micro-ROS's published figures beside them."""
    if shutil.which("arm-none-eabi-g++") is None:
        return [{"bench": BENCH, "skipped": "arm", "why": "arm-none-eabi-g++ is not installed"}]
    lines: list[dict[str, Any]] = []
    pss_ram: dict[str, int] = {}
    for board in ARM_BOARDS:
        cases = {
            "empty": _sketch(work / "plain_arm", "empty", EMPTY),
            "hello_world": LIBRARY_DIR / "examples" / "HelloWorld",
            "pub_sub_service": pss,
        }
        for case, sketch in cases.items():
            elf = build_sketch(sketch, board, work / "build" / f"{board}_{case}")
            size = arm_firmware_size(elf)
            line: dict[str, Any] = {
                "bench": BENCH,
                "case": case,
                "board": board,
                "flash": size.flash,
                "sram": size.sram,
            }
            if case in avr:
                line |= {
                    "avr_flash": avr[case]["flash"],
                    "avr_sram": avr[case]["sram"],
                    "flash_vs_avr": _ratio(size.flash, avr[case]["flash"]),
                    "sram_vs_avr": _ratio(size.sram, avr[case]["sram"]),
                }
            if case == "pub_sub_service":
                pss_ram[board] = size.sram
            lines.append(line)
    floor = (
        MICRO_ROS["publisher_ram"]
        + MICRO_ROS["subscriber_ram"]
        + MICRO_ROS["service_ram"]
        + MICRO_ROS["rmw_history_static_ram"]
    )
    lines.append(
        {"bench": BENCH, "case": "pub_sub_service", "peer": "micro-ROS"}
        | MICRO_ROS
        | {"floor_pub_sub_service_ram": floor}
        | {f"hwbridge_sram_{board}": ram for board, ram in pss_ram.items()}
        | {f"ratio_{board}": _ratio(ram, floor) for board, ram in pss_ram.items()}
    )
    return lines


if __name__ == "__main__":
    sys.exit(main())
