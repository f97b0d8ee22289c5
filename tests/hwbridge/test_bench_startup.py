"""tools/bench/startup.py runs (one launch per protocol) and prints the documented fields.

No timing is checked: the figures depend on the machine and its load.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).parents[2] / "tools" / "bench" / "startup.py"
FIELDS = {"bench", "hwbridge_s", "goal_s", "import_s", "peer", "peer_s", "ratio", "runs"}


def test_startup_bench_runs_once_per_protocol_and_prints_its_fields() -> None:
    done = subprocess.run(
        [sys.executable, str(BENCH), "--runs", "1"],
        capture_output=True,
        text=True,
        timeout=240,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    lines = [json.loads(line) for line in done.stdout.splitlines()]
    assert [line["bench"] for line in lines] == ["startup_native_pty", "startup_rosserial_pty"]
    for line in lines:
        assert set(line) >= FIELDS, line
        assert line["hwbridge_s"] > 0
        assert line["import_s"] > 0
        assert (
            line["goal_s"]
            == {"startup_native_pty": 1.0, "startup_rosserial_pty": 1.2}[line["bench"]]
        )
        assert line["runs"] == 1
        assert line["peer"] is None  # rosserial_python is not installable here
