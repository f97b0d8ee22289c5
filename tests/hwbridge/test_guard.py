"""Graph callbacks on Zenoh's threads: a failure is logged, unless the graph was closed under
the callback (Ctrl-C while discovery was subscribing: the session is gone, nothing is wrong)."""

from __future__ import annotations

import logging

import pytest

from hwbridge.graph.guard import call_guarded


def _subscribe_after_close() -> None:
    raise RuntimeError("session closed")


@pytest.mark.parametrize("closed", [None, False, True])
def test_a_failing_callback_is_logged_unless_the_graph_closed_under_it(
    closed: bool | None, caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.ERROR, logger="hwbridge.graph"):
        call_guarded(_subscribe_after_close, closed=None if closed is None else lambda: closed)
    failed = [r for r in caplog.records if "failed" in r.getMessage()]
    assert len(failed) == (0 if closed else 1)
    if failed:
        assert failed[0].exc_info is not None  # with its traceback
