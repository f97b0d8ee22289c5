"""``hwbridge demo`` states one distance driven: its table's last picture and its last line
(``odometry error: E% of D m``) give the same number, and nothing else states another."""

from __future__ import annotations

import os
import re
import subprocess
import sys

from tests.netutil import free_port


def test_the_demo_states_one_distance() -> None:
    env = {
        **os.environ,
        "HWBRIDGE_ENDPOINT": f"tcp/127.0.0.1:{free_port()}",
        "HWBRIDGE_DOMAIN": "demodistance",
    }
    done = subprocess.run(
        [sys.executable, "-m", "hwbridge", "demo", "--duration", "4", "--no-plot"],
        env=env,
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert done.returncode == 0, done.stderr + done.stdout
    last = re.fullmatch(r"odometry error: [0-9.]+% of ([0-9.]+) m", done.stdout.splitlines()[-1])
    assert last, done.stdout
    in_table = re.findall(r"distance driven\W+([0-9.]+) m", done.stdout)
    assert in_table and in_table[-1] == last[1], done.stdout
    assert "drove" not in done.stdout, done.stdout
