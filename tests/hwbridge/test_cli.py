"""The ``hwbridge`` command line: msg/srv commands, exit statuses and messages."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from hwbridge import __version__
from hwbridge.cli import main
from hwbridge.protocols.msgtypes import BUNDLED_MSG_DIR
from tests.cliutil import run_hwbridge

VECTORS = json.loads((BUNDLED_MSG_DIR.parent / "vectors" / "md5.json").read_text())


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("vector", VECTORS["messages"], ids=lambda v: v["type"])
def test_msg_md5_prints_the_md5_alone(
    capsys: pytest.CaptureFixture[str], vector: dict[str, str]
) -> None:
    assert run(capsys, "msg", "md5", vector["type"]) == (0, vector["md5"] + "\n", "")


@pytest.mark.parametrize("vector", VECTORS["services"], ids=lambda v: v["type"])
def test_srv_md5(capsys: pytest.CaptureFixture[str], vector: dict[str, str]) -> None:
    assert run(capsys, "srv", "md5", vector["type"]) == (0, vector["md5"] + "\n", "")


def test_console_script_in_a_real_process() -> None:
    script = Path(sys.executable).with_name("hwbridge")
    command = [str(script)] if script.exists() else [sys.executable, "-m", "hwbridge"]
    done = subprocess.run(
        [*command, "msg", "md5", "sensor_msgs/Imu"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert (done.returncode, done.stdout, done.stderr) == (
        0,
        "6a62c6daae103f4ff57a132d6f95cec2\n",
        "",
    )
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "msg", "md5", "nav_msgs/Odom"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 1
    assert done.stdout == ""
    assert "unknown message type 'nav_msgs/Odom'" in done.stderr
    assert "nav_msgs/Odometry" in done.stderr


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    assert run(capsys, "--version") == (0, f"hwbridge {__version__}\n", "")


def test_usage_errors_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "msg", "md5", "--no-such-option", "std_msgs/String")
    assert code == 2
    assert "No such option" in err
    code, _, err = run(capsys, "msg", "md5")
    assert code == 2
    assert "Missing argument" in err
    code, _, err = run(capsys, "no-such-command")
    assert code == 2


def test_unknown_type_exits_1_with_suggestion(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "msg", "show", "geometry_msgs/Twistt")
    assert (code, out) == (1, "")
    assert "did you mean geometry_msgs/Twist" in err
    code, out, err = run(capsys, "srv", "show", "std_srvs/Trig")
    assert code == 1
    assert "std_srvs/Trigger" in err


def test_msg_list_and_show(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "msg", "list", "rosserial_msgs")
    assert (code, out) == (0, "rosserial_msgs/Log\nrosserial_msgs/TopicInfo\n")
    code, out, _ = run(capsys, "msg", "list")
    assert code == 0
    assert {"std_msgs/String", "sensor_msgs/Imu", "tf2_msgs/TFMessage"} <= set(out.split())
    code, _, err = run(capsys, "msg", "list", "sensor_msg")
    assert code == 1
    assert "unknown package 'sensor_msg'; did you mean sensor_msgs" in err
    code, out, _ = run(capsys, "msg", "show", "rosserial_msgs/Log")
    assert out.splitlines()[0] == "uint8 ROSDEBUG=0"
    assert out.splitlines()[-1] == "string msg"


def test_srv_show(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "srv", "show", "rosserial_msgs/RequestParam")
    assert (code, out) == (
        0,
        "string name\n---\nint32[] ints\nfloat32[] floats\nstring[] strings\n",
    )
    assert run(capsys, "srv", "show", "std_srvs/Empty") == (0, "---\n", "")


def test_msg_path_option_and_env(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "lab_msgs" / "msg").mkdir(parents=True)
    (tmp_path / "lab_msgs" / "msg" / "Ping.msg").write_text("uint32 count\n")
    code, out, _ = run(capsys, "--msg-path", str(tmp_path), "msg", "list", "lab_msgs")
    assert (code, out) == (0, "lab_msgs/Ping\n")
    assert run(capsys, "msg", "md5", "lab_msgs/Ping")[0] == 1
    monkeypatch.setenv("HWBRIDGE_MSG_PATH", os.pathsep.join(["", str(tmp_path)]))
    code, out, _ = run(capsys, "msg", "show", "lab_msgs/Ping")
    assert (code, out) == (0, "uint32 count\n")


def hwbridge(*argv: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """``hwbridge ARGV`` in a real process (with ``env`` over this one's environment)."""
    environ = {k: v for k, v in os.environ.items() if k != "HWBRIDGE_MSG_PATH"}
    return run_hwbridge(*argv, timeout=60, env={**environ, "COLUMNS": "200", **(env or {})})


def test_a_msg_path_that_is_no_folder(tmp_path: Path) -> None:
    """An explicit --msg-path that is no folder is a usage error naming it; a missing
    HWBRIDGE_MSG_PATH entry a warning naming it (the other entries still count)."""
    (tmp_path / "msgs" / "lab_msgs" / "msg").mkdir(parents=True)
    (tmp_path / "msgs" / "lab_msgs" / "msg" / "Ping.msg").write_text("uint32 count\n")
    msgs, typo, a_file = tmp_path / "msgs", tmp_path / "msgz", tmp_path / "Ping.msg"
    a_file.write_text("uint32 count\n")

    done = hwbridge("--msg-path", str(msgs), "msg", "show", "lab_msgs/Ping")
    assert (done.returncode, done.stdout, done.stderr) == (0, "uint32 count\n", "")
    for bad in (typo, a_file):
        done = hwbridge("--msg-path", str(bad), "msg", "show", "lab_msgs/Ping")
        assert (done.returncode, done.stdout) == (2, ""), done.stderr
        assert f"'--msg-path': Directory '{bad}'" in done.stderr
    outdir = tmp_path / "headers"
    for command in ("headers", "generate"):
        done = hwbridge("firmware", command, str(outdir), "--msg-path", str(typo), "lab_msgs/Ping")
        assert done.returncode == 2, done.stderr
        assert f"'--msg-path': Directory '{typo}' does not exist" in done.stderr
        assert not outdir.exists()

    path = os.pathsep.join([str(typo), str(msgs)])
    done = hwbridge("msg", "show", "lab_msgs/Ping", env={"HWBRIDGE_MSG_PATH": path})
    assert (done.returncode, done.stdout) == (0, "uint32 count\n"), done.stderr
    assert done.stderr.count("\n") == 1, done.stderr
    assert f"HWBRIDGE_MSG_PATH entry {typo} does not exist" in done.stderr


def test_an_unknown_type_names_the_folders_searched(tmp_path: Path) -> None:
    (tmp_path / "lab_msgs" / "msg").mkdir(parents=True)
    (tmp_path / "lab_msgs" / "msg" / "Ping.msg").write_text("uint32 count\n")
    done = hwbridge("--msg-path", str(tmp_path), "msg", "show", "lab_msgs/Pong")
    assert done.returncode == 1
    assert (
        f"unknown message type 'lab_msgs/Pong' (searched {tmp_path.resolve()} and the built-in "
        "types); did you mean lab_msgs/Ping"
    ) in done.stderr
    done = hwbridge("msg", "show", "lab_msgs/Ping")  # no search path: nothing to name
    assert "error: unknown message type 'lab_msgs/Ping'; did you mean" in done.stderr


def test_bad_definition_on_path_is_reported(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "lab_msgs" / "msg").mkdir(parents=True)
    bad = tmp_path / "lab_msgs" / "msg" / "Bad.msg"
    bad.write_text("uint32 count\nunit8 flags\n")
    code, out, err = run(capsys, "--msg-path", str(tmp_path), "msg", "list")
    assert (code, out) == (1, "")
    assert f"{bad}:2: unknown type 'lab_msgs/unit8'" in err
    assert "did you mean uint8" in err
