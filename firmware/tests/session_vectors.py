"""Writes the transcript of protocols/vectors/native_session.json (PROTOCOL.md 2.12) as the line
format test_session.cpp reads on stdin: ``T NAME DIRECTION HEX`` (DIRECTION ``h`` for
host->device, ``d`` for device->host), then the service calls of ``extra`` (2.12 P, Q and R) as
``X NAME DIRECTION HEX``. Standard library only.

    python3 firmware/tests/session_vectors.py | BUILD/test_session
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def lines(root: Path = ROOT) -> list[str]:
    """The transcript, one frame a line, in order."""
    session = json.loads((root / "protocols/vectors/native_session.json").read_text())
    out = []
    for v in session["transcript"]:
        direction = "h" if v["direction"] == "host->device" else "d"
        out.append(f"T {v['name']} {direction} {v['hex'].replace(' ', '')}")
    # the service calls of PROTOCOL.md 2.12 P, Q and R, replayed by service_channels() and
    # short_call_heads()
    for v in session["extra"]:
        if v["name"].startswith(("ack_in_data_", "service_channel_", "short_call_")):
            direction = "h" if v["direction"] == "host->device" else "d"
            out.append(f"X {v['name']} {direction} {v['hex'].replace(' ', '')}")
    return out


if __name__ == "__main__":
    sys.stdout.write("".join(line + "\n" for line in lines()))
