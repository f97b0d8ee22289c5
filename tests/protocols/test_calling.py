"""``hwbridge.protocols.calling``: bursts of calls with pauses between them."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hwbridge.protocols.calling import (
    BOOTLOADER_QUIET,
    CALL_BURST,
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
    if at > now:  # a pause: it lasts until then, and is no longer than ``pause``
        assert not may_call(now, since, burst, pause)
        assert at - now <= pause + 1e-6
        for k in range(1, 8):
            assert not may_call(now + (at - now) * k / 8 * 0.999, since, burst, pause)


@settings(max_examples=200, derandomize=True)
@given(since=times, offset=st.floats(0.0, 1000.0, allow_nan=False))
def test_the_runtime_calls_at_most_a_burst_then_leaves_the_bootloader_its_quiet(
    since: float, offset: float
) -> None:
    """Within any 11 s (burst + quiet) from ``since`` on, calls are allowed for 5 s at most and
    there is a silence of 6 s: more than the stk500v2's 5 s wait after a byte."""
    now = since + offset
    allowed = [may_call(now + i * 0.01, since, CALL_BURST, BOOTLOADER_QUIET) for i in range(1100)]
    assert 499 <= sum(allowed) <= 501
    assert BOOTLOADER_QUIET > 5.0


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
