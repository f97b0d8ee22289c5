"""Bad files give one error line naming the file and line, never a traceback (issue 19 item 3)."""

from __future__ import annotations

import functools
import subprocess
from pathlib import Path

import pytest

from tests.cliutil import run_hwbridge

_hwbridge = functools.partial(run_hwbridge, timeout=60)


def _one_error(done: subprocess.CompletedProcess[str]) -> str:
    assert done.returncode == 1, done.stdout + done.stderr
    assert "Traceback" not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    return lines[0]


@pytest.mark.parametrize(
    ("files", "asked", "said"),
    [
        ({"Bin.msg": b"string \xff\xfe data\n"}, "bad_msgs/Bin", "Bin.msg:1: not UTF-8 text"),
        (
            {"Loop.msg": b"bad_msgs/Loop next\n"},
            "bad_msgs/Loop",
            "Loop.msg:1: bad_msgs/Loop contains itself",
        ),
        (
            {"A.msg": b"int32 x\nbad_msgs/B b\n", "B.msg": b"bad_msgs/A[] a\n"},
            "bad_msgs/A",
            "bad_msgs/A -> bad_msgs/B -> bad_msgs/A",
        ),
    ],
)
def test_bad_message_definitions(
    files: dict[str, bytes], asked: str, said: str, tmp_path: Path
) -> None:
    package = tmp_path / "bad_msgs" / "msg"
    package.mkdir(parents=True)
    for name, data in files.items():
        (package / name).write_bytes(data)
    line = _one_error(_hwbridge("--msg-path", str(tmp_path), "msg", "show", asked))
    assert said in line


def test_a_malformed_params_file(tmp_path: Path) -> None:
    params = tmp_path / "params.yaml"
    params.write_text("speed: 0.5\ngains: [1,\n")
    line = _one_error(_hwbridge("connect", "pty://", "--params", str(params)))
    assert line.startswith(f"error: {params}:") and "not valid YAML" in line


def test_a_malformed_robot_file_for_the_emulator(tmp_path: Path) -> None:
    robot = tmp_path / "robot.yaml"
    robot.write_text("robot: x\nboards: [\n")
    line = _one_error(_hwbridge("emulate", str(robot)))
    assert line.startswith(f"error: {robot}:") and "not valid YAML" in line


ROBOTS = Path(__file__).resolve().parents[2] / "examples" / "robots"


@pytest.mark.parametrize(
    "argv",
    [
        ["firmware", "headers", "{out}", "sensor_msgs/Range"],
        ["firmware", "generate", str(ROBOTS / "diffbot_uno.yaml"), "--out", "{out}", "--no-build"],
    ],
)
def test_an_output_folder_that_cannot_be_made(argv: list[str], tmp_path: Path) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("")  # a file where the output's parent folder should be
    out = blocker / "out"
    line = _one_error(_hwbridge(*(part.format(out=out) for part in argv)))
    assert line == f"error: {out}: Not a directory"
