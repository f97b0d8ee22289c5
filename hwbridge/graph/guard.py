"""Calling user callbacks from Zenoh's threads without letting an exception escape there."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

__all__ = ["call_guarded"]

log = logging.getLogger("hwbridge.graph")


def call_guarded(
    callback: Callable[..., Any], *args: Any, closed: Callable[[], bool] | None = None
) -> None:
    """``callback(*args)``; an exception is logged with its traceback, never raised.

    Graph callbacks run on Zenoh's threads, where an escaping exception would only be printed
    by Zenoh and lost; logging it under ``hwbridge.graph`` names the callback that failed.
    ``closed`` tells whether the graph has been closed: a callback that fails once it is (its
    session went away under it, as on Ctrl-C) is not an error, and nothing is logged.
    """
    try:
        callback(*args)
    except Exception:
        if closed is not None and closed():
            return
        log.exception("callback %r failed", callback)
