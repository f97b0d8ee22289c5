"""Longest test files first, on pytest-xdist's ``--dist loadfile`` (a pytest plugin).

A test file runs on one worker, and xdist hands files out in the order the workers collected
them (``tools/test`` passes ``--no-loadscope-reorder``; xdist's own order, most tests first,
left the files of one or two long end-to-end tests for last, one worker running them while
the other had nothing to do). Here the files are sorted by the seconds they took in a recorded
run, longest first, so that the short files fill in at the end: the classic longest-processing-
time-first schedule. A file not in the record keeps its place after the recorded ones; tests
keep their order within a file.

The record is ``tests/durations.json``: seconds per file (set-up, call and tear-down of every
test), written by a run with ``HWBRIDGE_TEST_DURATIONS=PATH`` in the environment, e.g.
``HWBRIDGE_TEST_DURATIONS=tests/durations.json ./tools/test``. A stale record only costs speed.
"""

from __future__ import annotations

import json
import os
from collections import defaultdict
from pathlib import Path

import pytest

RECORD = Path(__file__).with_name("durations.json")
RECORD_TO = "HWBRIDGE_TEST_DURATIONS"

_spent: defaultdict[str, float] = defaultdict(float)


def _file_of(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def recorded(path: Path = RECORD) -> dict[str, float]:
    """Seconds per test file from ``path`` (empty when there is no readable record)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict):
        return {}
    return {str(k): float(v) for k, v in data.items() if isinstance(v, int | float)}


def longest_first(nodeids: list[str], seconds: dict[str, float]) -> list[int]:
    """The order (indices into ``nodeids``) that runs recorded files longest first, the
    others after them in their collected order; a file's tests stay together and in order."""
    first_seen: dict[str, int] = {}
    for index, nodeid in enumerate(nodeids):
        first_seen.setdefault(_file_of(nodeid), index)

    def key(index: int) -> tuple[float, int, int]:
        name = _file_of(nodeids[index])
        return (-seconds.get(name, 0.0), first_seen[name], index)

    return sorted(range(len(nodeids)), key=key)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    seconds = recorded()
    if not seconds:
        return
    order = longest_first([item.nodeid for item in items], seconds)
    items[:] = [items[index] for index in order]


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    _spent[_file_of(report.nodeid)] += report.duration


def pytest_sessionfinish(session: pytest.Session) -> None:
    target = os.environ.get(RECORD_TO)
    if not target or hasattr(session.config, "workerinput") or not _spent:
        return  # nothing asked for, or an xdist worker (the controller sees every report)
    record = {name: round(_spent[name], 1) for name in sorted(_spent)}
    Path(target).write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")
