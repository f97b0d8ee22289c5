"""hwbridge: connect microcontroller boards to a host graph of topics and services."""


def _exit_early_on_signals() -> None:
    """In the ``hwbridge`` command only (console script or ``python -m hwbridge``): from here
    until ``main`` takes the signals over (:mod:`hwbridge.cli.stopping`), SIGINT or SIGTERM
    ends the process at once with 130 or 143. Nothing is open yet and nothing written, and a
    KeyboardInterrupt in the middle of the imports would only print a traceback after them.
    It runs first in this module, before any import of ours, so the window is as small as it
    can be."""
    import sys

    argv: list[str] = list(getattr(sys, "orig_argv", ()))
    module = argv[argv.index("-m") + 1] if "-m" in argv[:-1] else None
    script = sys.argv[0].rsplit("/", 1)[-1] if sys.argv else ""
    if module != "hwbridge" and script != "hwbridge":
        return
    import _signal  # type: ignore[import-not-found]  # built in; signal builds enums first
    import os

    def leave(signum: int, _frame: object) -> None:
        os.write(2, b"interrupted\n")
        os._exit(128 + signum)

    signals = (_signal.SIGINT, _signal.SIGTERM)
    for sig in signals:
        if _signal.getsignal(sig) in (_signal.default_int_handler, _signal.SIG_DFL):
            _signal.signal(sig, leave)
    # 'hwbridge ros2' starts itself again with the signals blocked across the exec: one that
    # came meanwhile is delivered now, to leave().
    _signal.pthread_sigmask(_signal.SIG_UNBLOCK, signals)


_exit_early_on_signals()

from hwbridge._version import __version__  # noqa: E402  # after the signals are handled

__all__ = ["__version__"]
