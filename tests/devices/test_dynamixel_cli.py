"""``hwbridge dxl scan|ping|read|write`` against emulated buses on real ptys.

The group is attached the way ``build_app`` attaches command groups; the subprocess tests run
the real ``hwbridge.cli.main`` in a fresh interpreter.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator

import pytest
import typer

import hwbridge.cli as cli
from hwbridge.cli.dxlcmd import dxl_app, parse_ids
from hwbridge.devices.dynamixel import EmulatedBusRunner
from tests.devices.dxl_helpers import serve

# Runs ``hwbridge`` with the dxl group attached (a no-op once build_app attaches it itself).
SHIM = """
import sys
import hwbridge.cli as cli
from hwbridge.cli.dxlcmd import dxl_app
build = cli.build_app
def with_dxl():
    app = build()
    if not any(group.name == "dxl" for group in app.registered_groups):
        app.add_typer(dxl_app, name="dxl")
    return app
cli.build_app = with_dxl
sys.exit(cli.main(sys.argv[1:]))
"""


PATIENT = "5"
"""``--timeout`` (seconds) of the calls a servo answers: the emulated bus answers whenever this
busy machine lets it run, which may be later than the commands' 0.05 s default for a real bus. A
servo that is there costs no more for it; absent ones get their own, short, timeouts."""


def patient(argv: tuple[str, ...]) -> list[str]:
    """``argv`` (``dxl COMMAND ...``) with ``--timeout PATIENT`` unless it sets its own."""
    if len(argv) < 2 or "--timeout" in argv:
        return list(argv)
    return [argv[0], argv[1], "--timeout", PATIENT, *argv[2:]]


def hwbridge(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", SHIM, *patient(argv)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def _has_dxl(app: typer.Typer) -> bool:
    return any(group.name == "dxl" for group in app.registered_groups)


@pytest.fixture(autouse=True)
def _dxl_attached(monkeypatch: pytest.MonkeyPatch) -> None:
    build = cli.build_app

    def with_dxl() -> typer.Typer:
        app = build()
        if not _has_dxl(app):
            app.add_typer(dxl_app, name="dxl")
        return app

    monkeypatch.setattr(cli, "build_app", with_dxl)


@pytest.fixture
def p2() -> Iterator[EmulatedBusRunner]:
    with serve("dxl-bus") as runner:
        yield runner


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = cli.main(patient(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize(
    ("bus_name", "options", "model"),
    [
        ("dxl-bus", [], "XL430-W250 (model 1060, firmware 45)"),
        ("dxl-bus-p1", ["--protocol", "1"], "AX-12A (model 12, firmware 24)"),
    ],
)
def test_scan_in_a_real_process(bus_name: str, options: list[str], model: str) -> None:
    with serve(bus_name) as runner:
        # (absent IDs 0, 3, 4 and 5 each wait out the timeout: half a second)
        done = hwbridge(
            "dxl", "scan", runner.slave_path, "--ids", "0-5", "--timeout", "0.5", *options
        )
        assert (done.returncode, done.stderr) == (0, "")
        assert done.stdout == f"servo 1: {model}\nservo 2: {model}\n"
        done = hwbridge("dxl", "scan", runner.slave_path, "--ids", "1,2", "--json", *options)
        assert [r["id"] for r in json.loads(done.stdout)] == [1, 2]


def test_errors_in_a_real_process(p2: EmulatedBusRunner) -> None:
    done = hwbridge("dxl", "ping", p2.slave_path, "9", "--timeout", "0.05")
    assert done.returncode == 1
    assert done.stderr.startswith("error: servo 9: no status packet for PING within 0.05 s")
    done = hwbridge("dxl", "write", p2.slave_path, "1", "torque_enable", "1")
    assert (done.returncode, done.stdout) == (0, "servo 1: wrote 1 to Torque Enable (64, 1 byte)\n")
    done = hwbridge("dxl", "write", p2.slave_path, "1", "operating_mode", "1")
    assert done.returncode == 1
    assert "error: servo 1: Access Error (EEPROM write while torque on)" in done.stderr


def test_ping_read_write(capsys: pytest.CaptureFixture[str], p2: EmulatedBusRunner) -> None:
    path = p2.slave_path
    assert run(capsys, "dxl", "ping", path, "2") == (
        0,
        "servo 2: XL430-W250 (model 1060, firmware 45)\n",
        "",
    )
    code, out, _ = run(capsys, "dxl", "ping", path, "2", "--json")
    assert json.loads(out) == {"id": 2, "model_number": 1060, "firmware": 45, "model": "XL430-W250"}
    code, out, _ = run(capsys, "dxl", "read", path, "1", "present_position")
    assert code == 0
    assert (
        out == "servo 1 Present Position (132, 4 bytes): 2048 [tick], 0.0000 rad  [00 08 00 00]\n"
    )
    code, out, _ = run(capsys, "dxl", "read", path, "1", "132", "4", "--json")
    assert json.loads(out) == {
        "id": 1,
        "register": "Present Position",
        "address": 132,
        "size": 4,
        "value": 2048,
        "bytes": "00080000",
        "value_rad": 0.0,
    }
    code, out, _ = run(capsys, "dxl", "read", path, "1", "0x84", "2")  # half of it: raw
    assert (code, out) == (0, "servo 1 raw (132, 2 bytes): 2048  [00 08]\n")
    code, _, err = run(capsys, "dxl", "write", path, "2", "--json", "Goal Position", "--", "-7")
    assert code == 1 and "Data Limit Error" in err  # negative values after --
    assert run(capsys, "dxl", "write", path, "2", "LED", "1", "--json")[1] == (
        '{"id": 2, "register": "LED", "address": 65, "size": 1, "value": 1, "ok": true}\n'
    )
    assert p2.call(lambda e: e.servo(2).get("LED")) == 1
    code, out, _ = run(capsys, "dxl", "write", path, "2", "65", "0")  # raw address
    assert code == 0 and p2.call(lambda e: e.servo(2).get("LED")) == 0
    code, out, _ = run(
        capsys, "dxl", "read", path, "2", "Present Velocity", "--model", "XL430-W250"
    )
    assert out.startswith("servo 2 Present Velocity (128, 4 bytes): 0 [0.229 rpm], 0.0000 rad/s")


def test_usage_and_lookup_errors(capsys: pytest.CaptureFixture[str], p2: EmulatedBusRunner) -> None:
    path = p2.slave_path
    code, _, err = run(capsys, "dxl", "read", path, "1", "present_postion")
    assert code == 1
    assert "no register 'present_postion' in the XL430-W250 control table" in err
    assert "did you mean Present Position" in err
    code, _, err = run(capsys, "dxl", "write", path, "1", "LED", "lots")
    assert code == 2 and "is not an integer" in err
    code, _, err = run(capsys, "dxl", "write", path, "1", "LED", "256")
    assert code == 2 and "does not fit" in err
    code, _, err = run(capsys, "dxl", "read", path, "1", "present_position", "2")
    assert code == 2 and "Present Position is 4 bytes, not 2" in err
    code, _, err = run(capsys, "dxl", "scan", path, "--ids", "9-3")
    assert code == 2 and "bad ID range" in err
    code, out, err = run(capsys, "dxl", "scan", path, "--ids", "7-9", "--timeout", "0.02", "--json")
    assert (code, out) == (1, "[]\n") and "no servo answered" in err


def test_an_unknown_model_option_lists_the_known_models(
    capsys: pytest.CaptureFixture[str], p2: EmulatedBusRunner
) -> None:
    code, out, err = run(
        capsys, "dxl", "read", p2.slave_path, "1", "present_position", "--model", "XL999"
    )
    assert (code, out) == (1, "")
    assert err.startswith(
        "error: unknown Dynamixel model 'XL999'; known: XL430-W250, XM430-W350, XM430-W210, AX-12A"
    )


def test_json_output_is_one_line_per_value(capsys: pytest.CaptureFixture[str]) -> None:
    """The one JSON writer behind every ``--json`` (dxl and the graph tools alike)."""
    from hwbridge.cli.common import emit_json

    emit_json({"id": 1, "value_rad": -0.5, "register": None, "ok": True})
    emit_json([])
    emit_json({"v": [float("inf"), (float("-inf"), float("nan"))], "ok": 1.5})
    assert capsys.readouterr().out == (
        '{"id": 1, "value_rad": -0.5, "register": null, "ok": true}\n[]\n'
        '{"v": ["Infinity", ["-Infinity", "NaN"]], "ok": 1.5}\n'
    )


def test_parse_ids() -> None:
    assert parse_ids("0-3") == [0, 1, 2, 3]
    assert parse_ids("5, 1-2,5") == [1, 2, 5]
    with pytest.raises(typer.BadParameter):
        parse_ids("1-x")


def test_dxl_is_a_registered_command_and_its_help_runs() -> None:
    """``python -m hwbridge dxl`` is a registered command and its help lists its subcommands."""
    from hwbridge.cli import COMMANDS

    assert "dxl" in COMMANDS
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "dxl", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0 and "scan" in done.stdout
