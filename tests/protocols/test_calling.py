"""``hwbridge.protocols.calling``: bursts of calls with pauses between them."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge.protocols.calling import (
    BOOTLOADER_QUIET,
    CALL_BURST,
    PAUSE_GROWTH,
    PAUSE_MAX,
    check_bursts,
    may_call,
    next_call,
)

times = st.floats(-100.0, 10_000.0, allow_nan=False)
bursts = st.one_of(st.just(0.0), st.floats(0.01, 20.0))
pauses = st.floats(0.01, 20.0, allow_nan=False)


@settings(max_examples=500, derandomize=True)
@given(now=times, since=times, burst=bursts, pause=pauses)
def test_next_call_is_the_first_moment_a_call_may_go(
    now: float, since: float, burst: float, pause: float
) -> None:
    at = next_call(now, since, burst, pause)
    assert at >= now
    assert may_call(at, since, burst, pause)
    if at > now:  # a pause: it lasts until then, and no pause is longer than the cap
        assert not may_call(now, since, burst, pause)
        assert at - now <= max(pause, PAUSE_MAX) + 1e-6
        for k in range(1, 8):
            assert not may_call(now + (at - now) * k / 8 * 0.999, since, burst, pause)


def _runs(
    since: float, burst: float, pause: float, span: float, step: float
) -> list[tuple[bool, float]]:
    """(calling?, length) of the runs of may_call sampled every ``step`` over ``span``."""
    runs: list[tuple[bool, float]] = []
    for i in range(round(span / step)):
        allowed = may_call(since + i * step, since, burst, pause)
        if runs and runs[-1][0] == allowed:
            runs[-1] = (allowed, runs[-1][1] + step)
        else:
            runs.append((allowed, step))
    return runs[:-1]  # the last run is cut off by the span


@settings(max_examples=25, derandomize=True)
@given(
    since=st.floats(-50.0, 1000.0),
    burst=st.floats(0.5, 8.0),
    pause=st.floats(0.5, 30.0),
)
def test_bursts_last_burst_and_pauses_grow_from_pause_to_the_cap(
    since: float, burst: float, pause: float
) -> None:
    step = 0.02
    runs = _runs(since, burst, pause, 12 * (burst + max(pause, PAUSE_MAX)), step)
    assert runs[0][0], "calls start at once"
    quiet = [length for calling, length in runs if not calling]
    loud = [length for calling, length in runs if calling]
    assert len(quiet) >= 6
    assert all(abs(length - burst) <= 2 * step for length in loud)
    assert abs(quiet[0] - pause) <= 2 * step
    longest = max(pause, PAUSE_MAX)
    for before, after in itertools.pairwise(quiet):
        expected = min(before * PAUSE_GROWTH, longest) if before < longest - 2 * step else before
        assert abs(after - expected) <= 3 * step * PAUSE_GROWTH
    assert abs(quiet[-1] - longest) <= 3 * step * PAUSE_GROWTH


def test_the_runtime_leaves_the_stk500v2_more_than_its_5_s() -> None:
    """The runtime's figures: 5 s of calls, then 6, 9, 13.5, 20, 20 ... s of silence; the Mega's
    bootloader needs 5 s after a byte."""
    runs = _runs(0.0, CALL_BURST, BOOTLOADER_QUIET, 150.0, 0.01)
    quiet = [round(length, 1) for calling, length in runs if not calling]
    assert quiet[:5] == [6.0, 9.0, 13.5, 20.0, 20.0]
    assert min(quiet) > 5.0


def test_no_burst_means_always() -> None:
    assert all(may_call(t, 0.0, 0.0, 6.0) for t in (0.0, 5.0, 7.0, 1e6))
    assert next_call(7.0, 0.0, 0.0, 6.0) == 7.0


def test_bad_bursts_are_refused_where_they_are_set() -> None:
    from hwbridge.protocols.native.session import HostConfig
    from hwbridge.protocols.rosserial.host import RosserialHost

    with pytest.raises(ValueError, match="call_burst >= 0 and call_pause > 0"):
        HostConfig(call_burst=-1.0)
    with pytest.raises(ValueError, match="call_burst >= 0 and call_pause > 0"):
        RosserialHost(call_pause=0.0)
    with pytest.raises(ValueError, match="need call_burst"):
        check_bursts(float("nan"), 6.0)
