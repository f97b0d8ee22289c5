"""How a command stops on SIGINT (Ctrl-C) or SIGTERM, at any moment of its life.

:func:`install` (called by :func:`hwbridge.cli.main`) takes over both signals for the whole
run. The first signal:

- sets :data:`STOP`, the event long-running commands wait on, and calls the callbacks given to
  :func:`on_signal` (a recorder finishing its file, a player stopping);
- raises KeyboardInterrupt in the main thread, unless the main thread is in a
  :func:`shielded` block (a steady-state wait on :data:`STOP`, or a command that stops through
  its callback): start-up (imports, opening the graph, waiting for discovery) is abandoned
  there and then, and the ``finally`` blocks on the way out close what was opened;
- arms a deadline: if the process is still running :data:`GRACE` seconds later (a C library
  that does not return, a close that hangs), it writes what is buffered and ends with
  ``os._exit`` (status 130 for SIGINT, 143 for SIGTERM), saying so on stderr.

A second signal ends the process at once, the same way.

Python runs signal handlers only in the main thread and only between bytecodes, so a main
thread blocked in C (``zenoh.open`` of a router, a join) would not see the signal until it
returns. The signals therefore also go through ``signal.set_wakeup_fd`` to a small watcher
thread, which sets :data:`STOP`, runs the callbacks and arms the deadline whatever the main
thread is doing.

After a signal, :func:`hwbridge.cli.main` ends the process with ``os._exit`` once the command
has returned and stdout and stderr are flushed: the interpreter's own finalization would tear
down Zenoh's and rclpy's threads while they may be in C code, which glibc reports as
``FATAL: exception not rethrown`` and an abort. Without a signal, :func:`leave` ends a
``hwbridge`` process the same way once its command returned (``hwbridge.cli.entry``).

Before :func:`install`, from the first import of :mod:`hwbridge` in a ``hwbridge`` process, a
signal ends the process at once (``hwbridge/__init__.py``): nothing is open yet. Earlier
still (the interpreter starting, site-packages' ``.pth`` hooks), Python's own handling applies:
no hwbridge code has run.
"""

from __future__ import annotations

import _thread
import atexit
import contextlib
import faulthandler
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Final, NoReturn

__all__ = [
    "GRACE",
    "STOP",
    "exit_now",
    "install",
    "leave",
    "on_signal",
    "shielded",
    "signalled",
    "wait_for_stop",
]

GRACE: Final = 1.5
"""Seconds from the first signal to the forced exit (the promise is: gone within 2 s)."""

STOP: Final = threading.Event()
"""Set by the first SIGINT or SIGTERM."""

_SIGNALS: Final = (signal.SIGINT, signal.SIGTERM)
_TRACE_ENV: Final = "HWBRIDGE_STOP_TRACE"
"""When set, a forced exit first dumps every thread's stack to stderr (to see what hung)."""


class _State:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.signum: int | None = None  # the first signal
        self.count = 0  # signals seen by the watcher
        self.raised = False  # the KeyboardInterrupt has been raised in the main thread
        self.shield = 0  # depth of shielded blocks in the main thread
        self.callbacks: list[Callable[[], None]] = []
        self.nudges = 0  # interruptions of our own (_nudge) the watcher will also see
        self.settled = False  # the main thread reached code that watches STOP: no more nudges


_state = _State()


def signalled() -> int | None:
    """The first stop signal received (None: none yet)."""
    return _state.signum


def _exit_status(signum: int | None) -> int:
    return 128 + (signum or signal.SIGINT)


def install() -> Callable[[], None] | None:
    """Take over SIGINT and SIGTERM (main thread only); returns what restores the previous
    handlers, or None when nothing was installed (another thread)."""
    if threading.current_thread() is not threading.main_thread():
        return None
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    watcher = threading.Thread(target=_watch, args=(read_fd,), name="hwbridge-signals", daemon=True)
    watcher.start()  # first: a KeyboardInterrupt must not land in start()'s wait
    previous_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    previous = {sig: signal.getsignal(sig) for sig in _SIGNALS}
    for sig in _SIGNALS:
        if previous[sig] is not signal.SIG_IGN:  # e.g. nohup, or a shell's background job
            signal.signal(sig, _on_signal_in_main)

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)
        signal.set_wakeup_fd(previous_fd)
        os.close(write_fd)  # the watcher reads end-of-file and returns
        watcher.join(1.0)
        os.close(read_fd)

    return restore


def _on_signal_in_main(signum: int, frame: FrameType | None) -> None:
    """Python's handler (main thread): break out of start-up unless shielded. The watcher
    thread does the rest (it may run first or second: both read only plain flags).

    In the import system's own code (where an exception may be dropped, "Exception ignored
    in ...", or leave its locks taken) and in a ``__del__`` or a ``__set_name__``
    (:data:`_NOT_IN`), the handler raises nothing: it has the KeyboardInterrupt raised as the
    next function (or module body) outside them starts
    (:func:`_raise_on_next_call`), a few microseconds to milliseconds later. The watcher also
    interrupts the main thread again every 50 ms (:func:`_nudge`), for a main thread already
    traced by someone else (a debugger, coverage)."""
    if _state.signum is None:
        _state.signum = signum
    if _state.shield or _state.raised:
        return
    if _swallowing(frame):
        _raise_on_next_call()
        return
    _state.raised = True
    raise KeyboardInterrupt


_NOT_IN: Final = frozenset({"__del__", "__set_name__"})
"""Functions out of which a KeyboardInterrupt does not come as itself: one leaving a ``__del__``
is printed and dropped where the ``__del__`` was called; one leaving a ``__set_name__`` (a
class being made, as a module's import runs: numpy's ``cached_property``) is replaced by a
RuntimeError ("Error calling __set_name__", Python 3.11), a traceback and exit status 1."""


def _swallowing(frame: FrameType | None) -> bool:
    """Whether ``frame`` is where a KeyboardInterrupt must not be raised: the import system's
    code, or in a function of :data:`_NOT_IN` (the frame or a caller)."""
    if frame is None:
        return False
    if frame.f_code.co_filename.startswith("<frozen importlib"):
        return True
    caller: FrameType | None = frame
    while caller is not None:
        if caller.f_code.co_name in _NOT_IN:
            return True
        caller = caller.f_back
    return False


def _raise_on_next_call() -> None:
    """Main thread, from its signal handler: trace it until a function or module body starts
    outside the import system's code, and raise the KeyboardInterrupt there. Most of an import
    is spent in C (compiling, reading, stat) called from the import system, where a handler
    runs right after; waiting for a later interruption to land elsewhere took 0.2-1.1 s of
    start-up on a 2-core machine (``hwbridge emulate``'s imports). Nothing is done when the
    thread is traced already (a debugger, coverage): :func:`_nudge` does it then."""
    if sys.gettrace() is None:  # (already _interrupt_on_call after an earlier signal: kept)
        sys.settrace(_interrupt_on_call)


def _interrupt_on_call(frame: FrameType, event: str, _arg: object) -> None:
    """The main thread's trace function after a signal (:func:`_raise_on_next_call`); only
    "call" events reach it (it sets no local trace function). An exception raised here is
    raised in the frame that starts, and ends the tracing."""
    if _state.raised or _state.shield or _state.settled:
        sys.settrace(None)
        return
    if event != "call" or _swallowing(frame):
        return
    sys.settrace(None)
    _state.raised = True
    raise KeyboardInterrupt


def _nudge(deadline: float) -> None:
    """Until the main thread has its KeyboardInterrupt (or is shielded, or the deadline comes),
    deliver the signal to it again every 50 ms: the first one may have landed where it could
    not be raised (:func:`_swallowing`)."""
    while time.monotonic() < deadline - 0.1:
        time.sleep(0.05)
        with _state.lock:
            if _state.raised or _state.shield or _state.settled:
                return
            _state.nudges += 1  # the wakeup fd carries it to the watcher too
        _thread.interrupt_main(signal.SIGINT)


def _watch(read_fd: int) -> None:
    while True:
        try:
            data = os.read(read_fd, 64)
        except OSError:
            return
        if not data:
            return
        for signum in data:
            if signum in _SIGNALS:
                _trigger(signum)


def _trigger(signum: int) -> None:
    with _state.lock:
        if _state.nudges:  # our own interrupt_main, not the user's second signal
            _state.nudges -= 1
            return
        _state.count += 1
        first = _state.count == 1
        callbacks = list(_state.callbacks)
    if not first:
        exit_now(_exit_status(_state.signum), "second signal")
        return
    if _state.signum is None:
        _state.signum = signum
    STOP.set()
    deadline = time.monotonic() + GRACE
    threading.Thread(
        target=_deadline, args=(deadline,), name="hwbridge-stop-deadline", daemon=True
    ).start()
    if _state.shield == 0 and threading.main_thread().is_alive():
        threading.Thread(
            target=_nudge, args=(deadline,), name="hwbridge-stop-nudge", daemon=True
        ).start()
    for callback in callbacks:
        threading.Thread(target=_call, args=(callback,), name="hwbridge-stop", daemon=True).start()


def _call(callback: Callable[[], None]) -> None:
    with contextlib.suppress(Exception):
        callback()


def _deadline(deadline: float) -> None:
    while (left := deadline - time.monotonic()) > 0:
        time.sleep(left)
    exit_now(_exit_status(_state.signum), f"still stopping {GRACE:g} s after the signal")


def exit_now(status: int, reason: str | None = None) -> None:
    """Flush stdout and stderr (waiting at most 0.2 s for them) and end the process with
    ``os._exit(status)``; ``reason`` (if any) goes to stderr first."""
    _state.settled = True
    if reason is not None:
        with contextlib.suppress(OSError):
            os.write(2, f"hwbridge: {reason}: exiting now\n".encode())
        if os.environ.get(_TRACE_ENV):
            with contextlib.suppress(Exception):
                faulthandler.dump_traceback(all_threads=True)
    flusher = threading.Thread(target=_flush, name="hwbridge-flush", daemon=True)
    flusher.start()
    flusher.join(0.2)  # another thread may hold a stream's lock, writing to a full pipe
    os._exit(status)


def leave(status: int) -> NoReturn:
    """End a ``hwbridge`` process whose command returned: what the interpreter's exit does
    first (``threading``'s exit hooks, which close the graphs still open, the join of the
    non-daemon threads, the ``atexit`` handlers, the streams flushed however long a pipe
    takes), then ``os._exit(status)`` instead of the finalization that would follow. That
    finalization stops the threads Zenoh (and rclpy) started, and one caught calling into
    Python ends the process with glibc's ``FATAL: exception not rethrown`` and an abort (seen
    at the end of a successful ``hwbridge demo --firmware``)."""
    _state.settled = True
    shutdown = getattr(threading, "_shutdown", None)
    if callable(shutdown):
        with contextlib.suppress(Exception):
            shutdown()
    run_exit_functions = getattr(atexit, "_run_exitfuncs", None)
    if callable(run_exit_functions):
        with contextlib.suppress(Exception):
            run_exit_functions()
    _flush()
    os._exit(status)


def _flush() -> None:
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()


@contextlib.contextmanager
def shielded() -> Iterator[None]:
    """A block of the main thread that watches :data:`STOP` itself: a signal does not raise
    KeyboardInterrupt in it. One that arrived before the block still stops it at once: the
    block starts with :data:`STOP` set."""
    main = threading.current_thread() is threading.main_thread()
    if main:
        _state.settled = True  # plain stores: only this thread writes them, no lock a
        _state.shield += 1  # KeyboardInterrupt could leave taken
    try:
        yield
    finally:
        if main:
            _state.shield -= 1


@contextlib.contextmanager
def on_signal(callback: Callable[[], None]) -> Iterator[None]:
    """Call ``callback`` (on another thread) at the first signal while the block runs (at once
    if the signal came already), and shield the block: the command stops through the
    callback."""
    with _state.lock:
        _state.callbacks.append(callback)
        already = STOP.is_set()
    if already:
        _call(callback)
    try:
        with shielded():
            yield
    finally:
        with _state.lock:
            _state.callbacks.remove(callback)


def wait_for_stop() -> None:
    """Block until SIGINT or SIGTERM (the steady state of ``connect``, ``up``, ``viz``...)."""
    with shielded():
        while not STOP.wait(0.25):
            pass
