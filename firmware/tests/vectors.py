"""Writes protocols/vectors/native_frames.json (and the selective ACK of native_session.json) as
the line format test_vectors.cpp reads on stdin. Standard library only.

    python3 firmware/tests/vectors.py | BUILD/test_vectors
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TYPES = {"BEST_EFFORT": 0, "RELIABLE": 1, "ACK": 2}
FRAGS = {"WHOLE": 0, "FIRST": 1, "MIDDLE": 2, "LAST": 3}


def _hex(text: str) -> str:
    text = text.replace(" ", "")
    return text or "-"


def _frame(kind: str, name: str, wire: str, frame: dict[str, object]) -> str:
    payload = str(frame.get("payload_hex", frame.get("payload", "")))
    return (
        f"{kind} {name} {_hex(wire)} {TYPES[str(frame['type'])]} {frame['channel']} "
        f"{frame['seq']} {FRAGS[str(frame['frag'])]} {_hex(payload)}"
    )


def lines(root: Path = ROOT) -> list[str]:
    """The vectors, one line each."""
    frames = json.loads((root / "protocols/vectors/native_frames.json").read_text())
    # A frame that carries an ACK (ACK_IN_DATA, PROTOCOL.md 1.4) is an "A" line: the ACK last.
    out = [
        _frame("V", v["name"], v["hex"], v["frame"])
        if v["frame"].get("ack") is None
        else f"{_frame('A', v['name'], v['hex'], v['frame'])} {v['frame']['ack']}"
        for v in frames["vectors"]
    ]
    out += [_frame("D", v["name"], v["hex"], v["frame"]) for v in frames["decode_only"]]
    for v in frames["bad"]:
        out.append(f"B {v['name']} {_hex(v['hex'])} {v['expect']} {v.get('max_payload', '-')}")
    for v in frames["fragmentation"]:
        out.append(
            f"F {v['name']} {TYPES[v['type']]} {v['channel']} {v['first_seq']} "
            f"{v['max_payload']} {_hex(v['message_hex'])} {','.join(v['frames_hex'])}"
        )
    session = json.loads((root / "protocols/vectors/native_session.json").read_text())
    for v in session["extra"]:
        if v["name"] == "ack_selective":
            out.append(_frame("V", v["name"], v["hex"], v["frame"]))
            out.append(f"S {v['name']} {_hex(v['hex'])}")
    return out


if __name__ == "__main__":
    sys.stdout.write("".join(line + "\n" for line in lines()))
