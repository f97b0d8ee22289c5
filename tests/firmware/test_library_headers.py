"""The generated headers committed into the HwBridge library never go stale.

``firmware/HwBridge/src`` holds the output of ``hwbridge firmware generate`` (``hwbridge_msg.h``,
``hwbridge_control.h`` with its parts ``hwbridge_control_base.h``, ``_msgs.h`` and ``_board.h``,
``hwbridge_wire.h`` and one header per message or service type under ``PKG/Type.h``) so that
sketches build from the library alone, as Arduino users build. This test
regenerates exactly those types into a temporary folder with the command and compares every file
byte for byte; a difference names the file and says how to refresh the library.
"""

from __future__ import annotations

from pathlib import Path

from hwbridge.cli import main

LIBRARY_SRC = Path(__file__).resolve().parents[2] / "firmware" / "HwBridge" / "src"
REFRESH = "hwbridge firmware generate firmware/HwBridge/src " + "TYPES (see this test)"
TOP_HEADERS = ("hwbridge_msg.h", "hwbridge_wire.h", "hwbridge_msgdefs.h")
CONTROL_HEADERS = (
    "hwbridge_control.h",
    "hwbridge_control_base.h",
    "hwbridge_control_msgs.h",
    "hwbridge_control_board.h",
)
"""hwbridge_control.h and the parts it includes, each of them generated."""


def _committed() -> dict[str, Path]:
    """Generated headers in the library, by path relative to src/."""
    found = {
        p.relative_to(LIBRARY_SRC).as_posix(): p
        for p in LIBRARY_SRC.glob("*/*.h")
        if p.parent.name != "hwbridge"
    }
    for name in (*TOP_HEADERS, *CONTROL_HEADERS):
        found[name] = LIBRARY_SRC / name
    return found


def test_generated_headers_are_current(tmp_path: Path) -> None:
    committed = _committed()
    types = sorted(name[: -len(".h")] for name in committed if "/" in name)
    assert "std_msgs/String" in types and "std_srvs/Trigger" in types
    assert main(["firmware", "generate", str(tmp_path), *types]) == 0
    fresh = {p.relative_to(tmp_path).as_posix(): p for p in tmp_path.rglob("*.h")}
    assert sorted(fresh) == sorted(committed), f"regenerate with: {REFRESH} {' '.join(types)}"
    stale = [
        name for name in sorted(fresh) if fresh[name].read_bytes() != committed[name].read_bytes()
    ]
    assert not stale, f"stale in firmware/HwBridge/src: {stale}; regenerate with: {REFRESH}"


def test_the_control_headers_are_the_generated_ones() -> None:
    """The control headers compared above are the generator's, and hwbridge_control.h (what the
    library and sketches include) includes each of its parts."""
    from hwbridge.firmware.gen_control import CONTROL_NAMES, generate_control_files

    assert set(CONTROL_NAMES) == set(CONTROL_HEADERS)
    assert set(generate_control_files()) == {*CONTROL_HEADERS, "hwbridge_wire.h"}
    control = (LIBRARY_SRC / "hwbridge_control.h").read_text()
    for part in CONTROL_HEADERS[1:]:
        assert f'#include "{part}"' in control, part


def test_the_library_types_are_the_committed_headers() -> None:
    """LIBRARY_TYPES (what the host hashes to expect a board's messages hash) lists exactly the
    library's headers, and the hash in hwbridge_msgdefs.h is the host's."""
    from hwbridge.firmware.gen_msgs import LIBRARY_TYPES, library_messages_hash
    from hwbridge.msg import registry

    types = sorted(name[: -len(".h")] for name in _committed() if "/" in name)
    assert sorted(LIBRARY_TYPES) == types
    defs = (LIBRARY_SRC / "hwbridge_msgdefs.h").read_text()
    assert f'#define HWBRIDGE_MSGS_HASH "{library_messages_hash(registry())}"' in defs


def test_library_version_is_the_properties_version() -> None:
    """HWBRIDGE_LIBRARY_VERSION (sent in BOARD_INFO) is library.properties' version."""
    props = (LIBRARY_SRC.parent / "library.properties").read_text().splitlines()
    (version,) = [line.split("=", 1)[1] for line in props if line.startswith("version=")]
    identity = (LIBRARY_SRC / "hwbridge" / "identity.h").read_text()
    assert f'#define HWBRIDGE_LIBRARY_VERSION "{version}"' in identity


def test_library_covers_the_device_plugins_types() -> None:
    """Every raw message a device plugin's firmware driver sends or takes is in the library."""
    committed = _committed()
    for name in (
        "hwbridge_msgs/WheelTicks",
        "hwbridge_msgs/WheelTargets",
        "hwbridge_msgs/SonarEcho",
        "hwbridge_msgs/ImuRaw",
        "hwbridge_msgs/Bme280",
        "sensor_msgs/JointState",
        "std_msgs/Float64",
        "std_msgs/Bool",
        "std_srvs/SetBool",
        "std_srvs/Empty",
        "geometry_msgs/Twist",
        "sensor_msgs/Range",
        "sensor_msgs/Imu",
        "std_msgs/Header",
    ):
        assert f"{name}.h" in committed, name
