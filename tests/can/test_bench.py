"""tools/bench/can.py runs: its frame counts match what both stacks put on the bus, and both
move a few messages over python-can's virtual bus (speed is the benchmark's business)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

pytest.importorskip("pycyphal")

BENCH = Path(__file__).resolve().parents[2] / "tools" / "bench" / "can.py"


def _bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_can", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("bench_can", module)
    spec.loader.exec_module(module)
    return module


def test_frame_counts_match_the_bus() -> None:
    bench = _bench()
    for payload in bench.payloads().values():
        ours = bench.hwbridge_frames(payload, 64)
        theirs = bench.cyphal_frame_lengths(len(payload))
        seen_ours = bench.sniff(
            lambda ch, p=payload: bench.hwbridge_rate(p, 64, 3, ch), skip_claims=True
        )
        seen_theirs = bench.sniff(lambda ch, p=payload: bench.cyphal_rate(p, 3, ch))
        assert seen_ours == 3 * len(ours)
        assert seen_theirs == 3 * len(theirs)
        assert bench.bus_bits([len(f) for f in ours]) > 0
