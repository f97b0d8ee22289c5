"""Calling user callbacks from Zenoh's threads without letting an exception escape there."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

__all__ = ["call_guarded"]

log = logging.getLogger("hwbridge.graph")


def call_guarded(callback: Callable[..., Any], *args: Any) -> None:
    """``callback(*args)``; an exception is logged with its traceback, never raised.

    Graph callbacks run on Zenoh's threads, where an escaping exception would only be printed
    by Zenoh and lost; logging it under ``hwbridge.graph`` names the callback that failed.
    """
    try:
        callback(*args)
    except Exception:
        log.exception("callback %r failed", callback)
