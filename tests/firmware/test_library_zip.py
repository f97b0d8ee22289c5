"""``hwbridge firmware library --zip``: a zip the Arduino IDE's "Add .ZIP Library" takes (one top
folder ``HwBridge/`` with library.properties, src/ and examples/NAME/NAME.ino, nothing built),
and an example built from it as the IDE builds it (Debian's ``arduino-builder``, the zip
unpacked in a sketchbook's ``libraries/``)."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from hwbridge.errors import HwBridgeError
from hwbridge.firmware.build import LIBRARY_DIR
from hwbridge.firmware.libzip import REQUIRED_PROPERTIES, write_library_zip

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = sorted(p.name for p in (LIBRARY_DIR / "examples").iterdir() if p.is_dir())
CTAGS_PATTERN = (
    '"{cmd.path}" -u --language-force=c++ -f - --c++-kinds=svpf --fields=KSTtzns '
    '--line-directives "{source_file}"'
)


@pytest.fixture(scope="module")
def library_zip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The zip as a user makes it: the real command, run in a fresh process."""
    out = tmp_path_factory.mktemp("zip") / "dist" / "HwBridge.zip"
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "firmware", "library", "--zip", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"{out}: the HwBridge library"), done.stdout
    assert "Add .ZIP Library" in done.stdout
    return out


def test_the_zip_is_one_library_folder(library_zip: Path) -> None:
    with zipfile.ZipFile(library_zip) as archive:
        assert archive.testzip() is None
        names = archive.namelist()
        properties = archive.read("HwBridge/library.properties").decode("utf-8")
    assert {name.split("/", 1)[0] for name in names} == {"HwBridge"}
    assert "HwBridge/src/HwBridge.h" in names
    for header in (
        "hwbridge_control.h",
        "hwbridge_control_base.h",
        "hwbridge_control_msgs.h",
        "hwbridge_control_board.h",
        "hwbridge_wire.h",
    ):
        assert f"HwBridge/src/{header}" in names, header
    for example in EXAMPLES:
        assert f"HwBridge/examples/{example}/{example}.ino" in names, example
    inos = [name for name in names if name.endswith(".ino")]
    assert len(inos) == len(EXAMPLES)
    for name in inos:
        parts = name.split("/")
        assert parts[:2] == ["HwBridge", "examples"] and parts[3] == f"{parts[2]}.ino", name
    for name in names:
        parts = name.rstrip("/").split("/")
        assert not any(p.startswith(".") or p in ("build", "__pycache__") for p in parts), name
        assert not name.endswith((".o", ".elf", ".hex", ".pyc", ".a")), name
    values = dict(line.split("=", 1) for line in properties.splitlines() if line and "=" in line)
    for key in (*REQUIRED_PROPERTIES, "includes"):
        assert values.get(key), key
    assert values["name"] == "HwBridge"
    assert values["includes"] == "HwBridge.h"
    assert values["architectures"] == "*"


def test_build_folders_stay_out_and_bad_libraries_are_refused(tmp_path: Path) -> None:
    library = tmp_path / "HwBridge"
    shutil.copytree(LIBRARY_DIR, library)
    built = library / "examples" / "Blink" / "build" / "uno"
    built.mkdir(parents=True)
    (built / "Blink.ino.hex").write_text(":00000001FF\n")
    (library / "src" / ".cache").mkdir()
    (library / "src" / ".cache" / "x.h").write_text("")
    (library / "src" / "stray.o").write_bytes(b"\0")
    names = write_library_zip(tmp_path / "out.zip", library)
    assert not [n for n in names if "/build/" in n or ".cache" in n or n.endswith(".o")]
    assert write_library_zip(tmp_path / "again.zip", library) == names
    assert (tmp_path / "out.zip").read_bytes() == (tmp_path / "again.zip").read_bytes()

    (library / "examples" / "Blink" / "Blink.ino").rename(library / "examples" / "Blink" / "B.ino")
    with pytest.raises(HwBridgeError, match=r"Blink: an example needs Blink.ino"):
        write_library_zip(tmp_path / "bad.zip", library)
    (library / "examples" / "Blink" / "B.ino").rename(library / "examples" / "Blink" / "Blink.ino")
    props = library / "library.properties"
    props.write_text(
        "\n".join(x for x in props.read_text().splitlines() if not x.startswith("sentence="))
    )
    with pytest.raises(HwBridgeError, match=r"library.properties: missing sentence"):
        write_library_zip(tmp_path / "bad.zip", library)
    assert not (tmp_path / "bad.zip").exists()


def test_without_zip_it_says_where_the_library_is() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "firmware", "library"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert (done.returncode, done.stdout) == (0, f"{LIBRARY_DIR}\n"), done.stderr


@pytest.mark.skipif(
    shutil.which("arduino-builder") is None, reason="needs the Debian package arduino-builder"
)
def test_an_example_builds_from_the_unpacked_zip(library_zip: Path, tmp_path: Path) -> None:
    libraries = tmp_path / "sketchbook" / "libraries"
    with zipfile.ZipFile(library_zip) as archive:
        archive.extractall(libraries)
    sketch = libraries / "HwBridge" / "examples" / "HelloWorld" / "HelloWorld.ino"
    out = tmp_path / "build"
    out.mkdir()
    done = subprocess.run(
        [
            "arduino-builder",
            "-hardware",
            "/usr/share/arduino/hardware",
            "-tools",
            "/usr/bin",
            "-libraries",
            str(libraries),
            "-fqbn",
            "arduino:avr:uno",
            "-prefs=compiler.cpp.extra_flags=-DDECIMAL_DIG=__DECIMAL_DIG__",
            "-prefs=tools.ctags.path=/usr/bin",
            "-prefs=tools.ctags.cmd.path=/usr/bin/arduino-ctags",
            f"-prefs=tools.ctags.pattern={CTAGS_PATTERN}",
            "-build-path",
            str(out),
            str(sketch),
        ],
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )
    output = done.stdout + done.stderr
    assert done.returncode == 0, output
    assert "Sketch uses" in output, output
    assert (out / "HelloWorld.ino.hex").is_file()
