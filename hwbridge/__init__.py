"""hwbridge: connect microcontroller boards to a host graph of topics and services."""

import sys as _sys

from hwbridge._version import __version__

_EARLY_SIGNALS: list[int] = []
"""SIGINT or SIGTERM received by the ``hwbridge`` command before its ``main`` took the signals
over (see :mod:`hwbridge.cli.stopping`)."""


def _hold_early_signals() -> None:
    """In the ``hwbridge`` command only (console script or ``python -m hwbridge``): from here
    to ``main``, note SIGINT and SIGTERM instead of raising KeyboardInterrupt in the middle of
    the imports (a traceback); ``main`` then exits at once with 130."""
    argv = list(getattr(_sys, "orig_argv", ()))
    module = argv[argv.index("-m") + 1] if "-m" in argv[:-1] else None
    script = _sys.argv[0].rsplit("/", 1)[-1] if _sys.argv else ""
    if module != "hwbridge" and script != "hwbridge":
        return
    import signal

    def note(signum: int, _frame: object) -> None:
        _EARLY_SIGNALS.append(signum)

    signals = (signal.SIGINT, signal.SIGTERM)
    for sig in signals:
        if signal.getsignal(sig) in (signal.default_int_handler, signal.SIG_DFL):
            signal.signal(sig, note)
    # 'hwbridge ros2' starts itself again with the signals blocked across the exec: what came
    # meanwhile is delivered now, to note().
    signal.pthread_sigmask(signal.SIG_UNBLOCK, signals)


_hold_early_signals()

__all__ = ["__version__"]
