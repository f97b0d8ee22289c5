"""The :class:`Link` contract shared by every byte link, and helpers for writing links.

A link moves bytes between the host and one board. It is blocking and meant for threads: the
bridge runs one reader thread per link that calls :meth:`Link.read` in a loop, while other
threads call :meth:`Link.write`; :meth:`Link.close` from any thread wakes both up promptly.

Public methods (``open``, ``read``, ``write``, ``close``) hold the locks, keep the counters and
the state; subclasses implement the protected hooks (``_open``, ``_read``, ``_write``, ``_wake``,
``_close``), as python-can's ``BusABC`` splits ``send`` and ``_send``.

States and what the bridge can rely on:

* *closed* (after creation or :meth:`~Link.close`): ``read``/``write`` raise
  :class:`LinkClosedError` with ``local=True``.
* *open*: ``read`` returns the bytes available (at least one) or ``b""`` on timeout.
* *lost*: a ``read`` or ``write`` found the peer or the device gone and raised
  :class:`LinkClosedError` (``local=False``); ``is_open`` is now False and later calls raise the
  same error until :meth:`~Link.open` reconnects (it releases the old resources first). Links that
  keep listening for the next peer (``tcp-listen://``, ``pty://``) stay open instead: the error
  marks the end of one peer session, and the next ``read`` waits for the next peer.
"""

from __future__ import annotations

import abc
import contextlib
import difflib
import enum
import logging
import math
import socket
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass
from types import TracebackType
from typing import Any, ClassVar, Final, TypeVar
from urllib.parse import parse_qsl

from hwbridge.errors import LinkError

__all__ = [
    "COMMON_OPTIONS",
    "DEFAULT_READ_SIZE",
    "DEFAULT_READ_TIMEOUT",
    "Link",
    "LinkClosedError",
    "LinkStats",
    "OptionConverter",
    "Waker",
    "closest",
    "opt_bool",
    "opt_float",
    "opt_int",
    "opt_optional_bool",
    "opt_optional_float",
    "parse_options",
    "split_query",
]

log = logging.getLogger("hwbridge.links")

_L = TypeVar("_L", bound="Link")

DEFAULT_READ_SIZE: Final = 4096
DEFAULT_READ_TIMEOUT: Final = 0.1


class LinkClosedError(LinkError):
    """The link is closed: by this process (``local``) or because the peer or device went away.

    ``local`` is True when :meth:`Link.close` was called (or the link was never opened), False
    when the other side hung up, the cable was pulled or the connection was reset.
    """

    def __init__(self, message: str, *, local: bool = False) -> None:
        super().__init__(message)
        self.local = local


@dataclass
class LinkStats:
    """Counters of one link, kept across reopens (read them any time; they only grow)."""

    bytes_in: int = 0
    """Bytes returned by ``read``."""
    bytes_out: int = 0
    """Bytes accepted by ``write``."""
    reads: int = 0
    """``read`` calls that returned data (timeouts are not counted)."""
    writes: int = 0
    """``write`` calls that completed."""
    opens: int = 0
    """Successful ``open`` calls that opened the link (not the no-op ones)."""
    errors: int = 0
    """Failed ``open`` calls, and ``read``/``write`` calls that failed on an open link (lost
    peers included; calls on a closed link and wake-ups by ``close()`` do not count)."""

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict (for logs and JSON)."""
        return asdict(self)


class _State(enum.Enum):
    CLOSED = "closed"
    OPEN = "open"
    LOST = "lost"


class Link(abc.ABC):
    """A bidirectional byte link (serial port, socket, pty, in-memory pipe...) opened by URL.

    Subclasses implement ``_open``, ``_read``, ``_write`` and ``_close``, plus ``_wake`` if a
    blocked ``_read``/``_write`` needs help to return when :meth:`close` is called. Hooks run with
    the relevant lock held: ``_read`` under the read lock, ``_write`` under the write lock,
    ``_open``/``_close`` under both. A hook reports a vanished peer by raising
    :class:`LinkClosedError`, any other failure as :class:`~hwbridge.errors.LinkError`.
    """

    scheme: ClassVar[str] = ""
    """The URL scheme that names this kind of link (for messages)."""
    datagram: ClassVar[bool] = False
    """True if each read returns one whole datagram and each write sends one (UDP, CAN): the
    protocol then uses its datagram framing. False for byte streams (serial, TCP, pty)."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.stats = LinkStats()
        self._state = _State.CLOSED
        self._closing = False
        self._lifecycle_lock = threading.Lock()  # serializes open() and close()
        self._state_lock = threading.Lock()  # guards _state, _closing and stats.errors; never waits
        self._read_lock = threading.Lock()
        self._write_lock = threading.Lock()

    # ----------------------------------------------------------------------------- public API

    @property
    def is_open(self) -> bool:
        """True between a successful :meth:`open` and :meth:`close` or the loss of the peer."""
        return self._state is _State.OPEN and not self._closing

    @property
    def connected(self) -> bool:
        """True when a peer is known to be there (links that wait for peers override this)."""
        return self.is_open

    def open(self) -> None:
        """Open the link; a no-op when it is open; reconnects a link whose peer was lost.

        Raises :class:`~hwbridge.errors.LinkError` saying what failed, where, and what to do.
        """
        with self._lifecycle_lock:
            if self._state is _State.OPEN:
                return
            if self._state is _State.LOST:
                self._shutdown()
            try:
                self._open()
            except LinkError:
                self._count_error()
                raise
            except OSError as exc:
                self._count_error()
                raise LinkError(f"cannot open {self.url}: {exc}") from exc
            with self._state_lock:
                self._state = _State.OPEN
                self._closing = False
            self.stats.opens += 1
            log.debug("opened %s", self.url)

    def read(
        self, max_bytes: int = DEFAULT_READ_SIZE, timeout: float | None = DEFAULT_READ_TIMEOUT
    ) -> bytes:
        """Return 1 to ``max_bytes`` bytes as soon as some are available, or ``b""`` on timeout.

        ``timeout`` is in seconds; ``None`` waits until data comes, the peer goes or
        :meth:`close` is called; ``0`` only takes what is already there. Raises
        :class:`LinkClosedError` when the link is closed (also when :meth:`close` interrupts the
        wait) or the peer/device is gone, :class:`~hwbridge.errors.LinkError` on other failures.
        """
        if max_bytes < 1:
            raise ValueError(f"max_bytes must be at least 1, not {max_bytes}")
        if timeout is not None:
            if math.isnan(timeout):
                raise ValueError("timeout must be a number of seconds or None, not NaN")
            timeout = max(0.0, timeout)
        with self._read_lock:
            self._check_usable("read from")
            try:
                data = self._read(max_bytes, timeout)
            except LinkError as exc:
                error = self._failed(exc, "read from")
                if error is exc:
                    raise
                raise error from exc
            except OSError as exc:  # a hook should translate these; keep the contract anyway
                error = LinkError(f"read from {self.url} failed: {exc}")
                raise self._failed(error, "read from") from exc
        if data:
            self.stats.reads += 1
            self.stats.bytes_in += len(data)
            return data
        if self._closing or self._state is not _State.OPEN:
            raise self._closed_error("read from")
        return b""

    def write(self, data: bytes | bytearray | memoryview) -> None:
        """Send all of ``data`` or raise :class:`~hwbridge.errors.LinkError`; thread-safe.

        Concurrent writers do not interleave: each call's bytes go out in one piece. A write
        blocked by flow control returns (with :class:`LinkClosedError`) when :meth:`close` is
        called; links with a ``write_timeout`` option raise ``LinkError`` when it expires.
        """
        view = memoryview(data).cast("B")
        with self._write_lock:
            self._check_usable("write to")
            if not view:
                return
            try:
                self._write(view)
            except LinkError as exc:
                error = self._failed(exc, "write to")
                if error is exc:
                    raise
                raise error from exc
            except OSError as exc:
                error = LinkError(f"write to {self.url} failed: {exc}")
                raise self._failed(error, "write to") from exc
            self.stats.writes += 1
            self.stats.bytes_out += len(view)

    def transport_stats(self) -> dict[str, Any]:
        """Counters of the transport under the link beyond :attr:`stats` (a CAN bus's error
        frames, bus-off and drops); empty for most links. Shown by ``hwbridge board stats``."""
        return {}

    def close(self) -> None:
        """Close the link; idempotent. A ``read`` or ``write`` blocked in another thread returns
        promptly with :class:`LinkClosedError`."""
        with self._lifecycle_lock:
            if self._state is _State.CLOSED:
                return
            self._shutdown()
            log.debug("closed %s", self.url)

    def __enter__(self: _L) -> _L:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closing" if self._closing else self._state.value
        return f"<{type(self).__name__} {self.url!r} {state}>"

    # -------------------------------------------------------------------------- protected hooks

    @abc.abstractmethod
    def _open(self) -> None:
        """Acquire the resources (port, socket...); raise LinkError with an actionable message."""

    @abc.abstractmethod
    def _read(self, max_bytes: int, timeout: float | None) -> bytes:
        """Wait up to ``timeout`` (None: forever) for data; ``b""`` on timeout or once woken."""

    @abc.abstractmethod
    def _write(self, data: memoryview) -> None:
        """Send every byte of ``data`` (not empty); return early only by raising."""

    @abc.abstractmethod
    def _close(self) -> None:
        """Release the resources; called once per successful ``_open``, with no I/O running."""

    def _wake(self) -> None:  # noqa: B027 (an optional hook: most links need nothing here)
        """Make a blocked ``_read``/``_write`` return soon; called from another thread by
        :meth:`close` before it takes the locks. Must return promptly."""

    def _survives_peer_loss(self) -> bool:
        """Whether the link stays usable after its hook raised LinkClosedError (listeners)."""
        return False

    # ------------------------------------------------------------------------ subclass helpers

    @property
    def _stopping(self) -> bool:
        """True once :meth:`close` started: hooks use it to tell a wake-up from a timeout."""
        return self._closing

    def _closed_error(self, action: str) -> LinkClosedError:
        """The error for I/O on a link that this process closed (or is closing)."""
        return LinkClosedError(
            f"cannot {action} {self.url}: the link is closed (call open() first)", local=True
        )

    # -------------------------------------------------------------------------------- internals

    def _check_usable(self, action: str) -> None:
        if self._closing or self._state is _State.CLOSED:
            raise self._closed_error(action)
        if self._state is _State.LOST:
            raise LinkClosedError(
                f"cannot {action} {self.url}: the connection was lost; call open() to reconnect"
            )

    def _failed(self, exc: LinkError, action: str) -> LinkError:
        """Count a failed hook and update the state; returns the error to raise."""
        with self._state_lock:
            if isinstance(exc, LinkClosedError):
                if self._closing or self._state is _State.CLOSED:
                    return self._closed_error(action)  # woken by close(): not an error
                if not self._survives_peer_loss():
                    self._state = _State.LOST
            self.stats.errors += 1
        return exc

    def _count_error(self) -> None:
        with self._state_lock:
            self.stats.errors += 1

    def _shutdown(self) -> None:
        """Wake blocked I/O, wait for it to leave, release the resources (lifecycle lock held)."""
        with self._state_lock:
            self._closing = True
        try:
            self._wake()
        except (OSError, LinkError) as exc:
            log.debug("waking I/O on %s failed: %s", self.url, exc)
        with self._read_lock, self._write_lock:
            try:
                self._close()
            except (OSError, LinkError) as exc:
                log.debug("releasing %s failed: %s", self.url, exc)
            finally:
                with self._state_lock:
                    self._state = _State.CLOSED
                    self._closing = False


class Waker:
    """A socket pair to wake a thread blocked in ``select``; stays signalled once woken.

    Register :meth:`fileno` for reading next to the real file descriptor; :meth:`wake` makes it
    readable for good (a link recreates its waker on each open).
    """

    def __init__(self) -> None:
        self._reader, self._writer = socket.socketpair()
        self._reader.setblocking(False)
        self._writer.setblocking(False)
        self.woken = False

    def fileno(self) -> int:
        """The descriptor to wait on."""
        return self._reader.fileno()

    def wake(self) -> None:
        """Make waiters return; safe from any thread, never blocks."""
        self.woken = True
        with contextlib.suppress(OSError):  # buffer full (already signalled) or closed
            self._writer.send(b"\0")

    def close(self) -> None:
        """Release both sockets."""
        self._reader.close()
        self._writer.close()


# ------------------------------------------------------------------------------------- options

OptionConverter = Callable[[Any], Any]
"""Turns an option value (a string from a URL query, or a Python value from a kwarg) into the
value the link uses; raises ValueError (or TypeError) with a short description when it cannot."""

_TRUE: Final = frozenset({"1", "true", "yes", "on", ""})
_FALSE: Final = frozenset({"0", "false", "no", "off"})


def opt_bool(value: Any) -> bool:
    """``1/0, true/false, yes/no, on/off`` (a bare ``?flag`` means true) or a Python bool."""
    if isinstance(value, bool):
        return value
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    if isinstance(value, str):
        text = value.strip().lower()
        if text in _TRUE:
            return True
        if text in _FALSE:
            return False
    raise ValueError("expected 1/0, true/false, yes/no or on/off")


def opt_optional_bool(value: Any) -> bool | None:
    """Like :func:`opt_bool`, and ``None``/``"none"``/``"default"`` for "leave as it is"."""
    if value is None or (isinstance(value, str) and value.strip().lower() in ("none", "default")):
        return None
    return opt_bool(value)


def opt_int(value: Any) -> int:
    """An integer (decimal, or with a 0x/0o/0b prefix)."""
    if isinstance(value, bool):
        raise ValueError("expected an integer")
    if isinstance(value, int):
        return value
    if isinstance(value, str):
        try:
            return int(value.strip(), 0)
        except ValueError:
            pass
    raise ValueError("expected an integer")


def opt_float(value: Any) -> float:
    """A finite number."""
    if isinstance(value, bool):
        raise ValueError("expected a number")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError("expected a number") from None
    if not math.isfinite(number):
        raise ValueError("expected a finite number")
    return number


def opt_optional_float(value: Any) -> float | None:
    """A non-negative number of seconds, or ``None``/``"none"`` for no limit."""
    if value is None or (isinstance(value, str) and value.strip().lower() == "none"):
        return None
    number = opt_float(value)
    if number < 0:
        raise ValueError("expected a number of seconds >= 0, or none")
    return number


COMMON_OPTIONS: Final[Mapping[str, OptionConverter]] = {
    "write_timeout": opt_optional_float,
}
"""Options every built-in link takes: ``write_timeout`` (seconds; default none = wait)."""


def closest(word: str, choices: Iterable[str]) -> str | None:
    """The choice most like ``word`` (for "did you mean" hints), or None if none is close."""
    matches = difflib.get_close_matches(word.lower(), sorted(choices), n=1, cutoff=0.5)
    return matches[0] if matches else None


def split_query(query: str, url: str) -> dict[str, str]:
    """The ``key=value`` pairs of a URL query; a key given twice is an error."""
    pairs: dict[str, str] = {}
    for key, value in parse_qsl(query, keep_blank_values=True):
        name = key.strip().lower()
        if name in pairs:
            raise LinkError(f"option {name!r} is given twice in {url!r}; keep one")
        pairs[name] = value
    return pairs


def parse_options(
    url: str,
    spec: Mapping[str, OptionConverter],
    query: Mapping[str, str],
    kwargs: Mapping[str, Any],
) -> dict[str, Any]:
    """Merge query-string and keyword options (keywords win), check names and convert values.

    Raises LinkError naming the option, the closest known one, or the expected value.
    """
    merged: dict[str, Any] = {**query, **{k.lower(): v for k, v in kwargs.items()}}
    result: dict[str, Any] = {}
    for name, value in merged.items():
        converter = spec.get(name)
        if converter is None:
            hint = closest(name, spec)
            known = ", ".join(sorted(spec)) or "none"
            did_you_mean = f"; did you mean {hint!r}?" if hint else ""
            raise LinkError(
                f"unknown option {name!r} for {url!r}{did_you_mean} (options here: {known})"
            )
        try:
            result[name] = converter(value)
        except (TypeError, ValueError) as exc:
            raise LinkError(f"bad value {value!r} for option {name!r} in {url!r}: {exc}") from None
    return result
