"""Writes protocols/vectors/can_frames.json (format 1), can_frames_v2.json (format 2) and
can_chains.json (chained transfers, CAN.md 12) as the lines test_can_vectors.cpp reads on stdin
(standard library only; "-" stands for no bytes):

    crc INPUT CRC
    id PRIORITY KIND CHANNEL DESTINATION SOURCE ID
    tx NAME MTU TID PAYLOAD N FRAME...
    dg NAME SOURCE DESTINATION MTU DATAGRAM N ID:DATA...
    bad NAME LOCAL EXPECT N ID:EXTENDED:DATA...
    id2 PRIORITY KIND CHANNEL DESTINATION SOURCE SEQ FRAG ID
    dg2 NAME SOURCE DESTINATION MTU DATAGRAM N ID:DATA...
    claim SOURCE TAKES_CHAINS ID
    ch NAME SOURCE DESTINATION MTU HOST_CLAIM_ID N DATAGRAM... N ID:DATA...

    python3 firmware/tests/can/can_vectors.py | BUILD/test_can_vectors
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]


def _hex(text: str) -> str:
    return text or "-"


def _name(text: str) -> str:
    return text.replace(" ", "_")


VECTORS = ROOT / "protocols" / "vectors"


def lines(path: Path = VECTORS / "can_frames.json") -> list[str]:
    return (
        format_1_lines(path)
        + format_2_lines(path.with_name("can_frames_v2.json"))
        + chain_lines(path.with_name("can_chains.json"))
    )


def chain_lines(path: Path) -> list[str]:
    doc = json.loads(path.read_text())
    out = []
    host_claim = ""
    for v in doc["claims"]:
        claim_id = v["frames"][0]["id"]
        out.append(f"claim {v['source']} {int(v['takes_chains'])} {claim_id}")
        if v["source"] == 0 and v["takes_chains"]:
            host_claim = claim_id
    for v in doc["chains"]:
        datagrams = " ".join(_hex(d) for d in v["datagrams_hex"])
        frames = " ".join(f"{f['id']}:{_hex(f['data_hex'])}" for f in v["frames"])
        out.append(
            f"ch {_name(v['name'])} {v['source']} {v['destination']} {v['mtu']} {host_claim} "
            f"{len(v['datagrams_hex'])} {datagrams} {len(v['frames'])} {frames}"
        )
    return out


def _bad(doc: dict) -> list[str]:
    out = []
    for v in doc["bad"]:
        frames = " ".join(
            f"{f['id']}:{int(f['extended'])}:{_hex(f['data_hex'])}" for f in v["frames"]
        )
        out.append(f"bad {_name(v['name'])} {v['local']} {v['expect']} {len(v['frames'])} {frames}")
    return out


def format_2_lines(path: Path) -> list[str]:
    doc = json.loads(path.read_text())
    out = []
    for v in doc["ids"]:
        f = v["fields"]
        out.append(
            f"id2 {f['priority']} {f['kind']} {f['channel']} {f['destination']} {f['source']} "
            f"{f['seq']} {f['frag']} {v['id']}"
        )
    for v in doc["datagrams"]:
        frames = " ".join(f"{f['id']}:{_hex(f['data_hex'])}" for f in v["frames"])
        out.append(
            f"dg2 {_name(v['name'])} {v['source']} {v['destination']} {v['mtu']} "
            f"{_hex(v['datagram_hex'])} {len(v['frames'])} {frames}"
        )
    return out + _bad(doc)


def format_1_lines(path: Path) -> list[str]:
    doc = json.loads(path.read_text())
    out = [f"crc {doc['crc_check']['input_hex']} {doc['crc_check']['crc16']}"]
    for v in doc["ids"]:
        f = v["fields"]
        out.append(
            f"id {f['priority']} {f['kind']} {f['channel']} {f['destination']} {f['source']} "
            f"{v['id']}"
        )
    for v in doc["transfers"]:
        frames = " ".join(_hex(x) for x in v["frames_hex"])
        out.append(
            f"tx {_name(v['name'])} {v['mtu']} {v['tid']} {_hex(v['payload_hex'])} "
            f"{len(v['frames_hex'])} {frames}"
        )
    for v in doc["datagrams"]:
        frames = " ".join(f"{f['id']}:{_hex(f['data_hex'])}" for f in v["frames"])
        out.append(
            f"dg {_name(v['name'])} {v['source']} {v['destination']} {v['mtu']} "
            f"{_hex(v['datagram_hex'])} {len(v['frames'])} {frames}"
        )
    return out + _bad(doc)


if __name__ == "__main__":
    sys.stdout.write("\n".join(lines()) + "\n")
