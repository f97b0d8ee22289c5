"""Serial ports through pyserial: ``serial:///dev/ttyACM0?baud=115200``, ``/dev/ttyUSB0``, ``COM3``.

Works on any device pyserial opens, pty slaves included (the emulator and the tests use those).
pyserial is imported when a serial link is created, not when ``hwbridge.links`` is.

Options (URL query or keyword): ``baud`` (default 115200), ``bytesize`` (5-8, default 8),
``parity`` (N/E/O/M/S or none/even/odd/mark/space), ``stopbits`` (1, 1.5, 2), ``rtscts``,
``dsrdtr``, ``xonxoff``, ``reset`` (1: pulse DTR/RTS after opening to reset an Arduino; 0: try to
keep DTR/RTS low so opening does not reset it, which some OSes assert anyway; default: leave them
as pyserial does), ``exclusive`` (default 1 on POSIX: lock the port so a second program cannot
read from it too), ``low_latency`` (default 1: ask the Linux driver for ``ASYNC_LOW_LATENCY``
where it supports it), ``write_timeout`` (seconds; default none: wait).

A port that disappears (USB cable pulled, the other end of a pty closed) makes ``read``/``write``
raise :class:`~hwbridge.links.base.LinkClosedError`; ``open()`` reopens it when it is back.
"""

from __future__ import annotations

import errno
import logging
import os
import select
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final
from urllib.parse import unquote, urlsplit

from hwbridge.errors import LinkError
from hwbridge.links._io import write_all
from hwbridge.links.base import (
    COMMON_OPTIONS,
    Link,
    LinkClosedError,
    Waker,
    opt_bool,
    opt_float,
    opt_int,
    opt_optional_bool,
    parse_options,
    split_query,
)

_POSIX = os.name == "posix"

if TYPE_CHECKING:
    import serial

__all__ = ["DEFAULT_BAUD", "SerialLink"]

log = logging.getLogger("hwbridge.links")

DEFAULT_BAUD: Final = 115200
_RESET_PULSE: Final = 0.1  # seconds DTR/RTS stay low for reset=1 (the Arduino tools use 0.25 max)
_UNSET: Final = object()

_PARITIES: Final = {
    "n": "N",
    "none": "N",
    "e": "E",
    "even": "E",
    "o": "O",
    "odd": "O",
    "m": "M",
    "mark": "M",
    "s": "S",
    "space": "S",
}


def _baud(value: Any) -> int:
    baud = opt_int(value)
    if baud <= 0:
        raise ValueError("expected a positive baud rate such as 115200")
    return baud


def _bytesize(value: Any) -> int:
    size = opt_int(value)
    if size not in (5, 6, 7, 8):
        raise ValueError("expected 5, 6, 7 or 8")
    return size


def _parity(value: Any) -> str:
    parity = _PARITIES.get(str(value).strip().lower())
    if parity is None:
        raise ValueError("expected N, E, O, M or S (none, even, odd, mark, space)")
    return parity


def _stopbits(value: Any) -> float:
    bits = opt_float(value)
    if bits not in (1, 1.5, 2):
        raise ValueError("expected 1, 1.5 or 2")
    return bits


_OPTIONS: Final = {
    **COMMON_OPTIONS,
    "baud": _baud,
    "bytesize": _bytesize,
    "parity": _parity,
    "stopbits": _stopbits,
    "rtscts": opt_bool,
    "dsrdtr": opt_bool,
    "xonxoff": opt_bool,
    "reset": opt_optional_bool,
    "exclusive": opt_optional_bool,
    "low_latency": opt_bool,
}


def _port_path(url: str) -> tuple[str, str]:
    """The device path and the query of a ``serial://`` URL or a bare path."""
    if "://" not in url:
        path, _, query = url.partition("?")
        return path, query
    parts = urlsplit(url)
    return unquote(parts.netloc + parts.path), parts.query


class SerialLink(Link):
    """A serial port opened with pyserial; see the module documentation for the options."""

    scheme = "serial"

    def __init__(self, url: str, **options: Any) -> None:
        super().__init__(url)
        self.port, query = _port_path(url)
        if not self.port:
            raise LinkError(
                f"{url!r} names no serial port: write serial:///dev/ttyACM0 (three slashes), "
                "serial://COM3, or just the path"
            )
        opts = parse_options(url, _OPTIONS, split_query(query, url), options)
        self.baud: int = opts.get("baud", DEFAULT_BAUD)
        self.bytesize: int = opts.get("bytesize", 8)
        self.parity: str = opts.get("parity", "N")
        self.stopbits: float = opts.get("stopbits", 1)
        self.rtscts: bool = opts.get("rtscts", False)
        self.dsrdtr: bool = opts.get("dsrdtr", False)
        self.xonxoff: bool = opts.get("xonxoff", False)
        self.reset: bool | None = opts.get("reset")
        self.exclusive: bool | None = opts.get("exclusive", True if os.name == "posix" else None)
        self.low_latency: bool = opts.get("low_latency", True)
        self.write_timeout: float | None = opts.get("write_timeout")
        self._serial: serial.Serial | None = None
        self._timeout: object = _UNSET
        # POSIX: pyserial opens, configures and closes the port; reads and writes go straight
        # to its (non-blocking) descriptor, which costs a few system calls less per call than
        # pyserial's read()/write() (a select and an ioctl each) on the bridge's hot path.
        self._fd: int | None = None
        self._waker: Waker | None = None
        self._poll: select.poll | None = None
        self._drained = False
        """The last read took less than it asked for: nothing is left (see ``_read_fd``)."""

    # ---------------------------------------------------------------------------------- hooks

    def _open(self) -> None:
        import serial

        port = serial.Serial()
        port.port = self.port
        port.baudrate = self.baud
        port.bytesize = self.bytesize
        port.parity = self.parity
        port.stopbits = self.stopbits
        port.rtscts = self.rtscts
        port.dsrdtr = self.dsrdtr
        port.xonxoff = self.xonxoff
        port.timeout = None
        port.write_timeout = self.write_timeout
        if self.exclusive is not None:
            port.exclusive = self.exclusive
        if self.reset is False:
            port.dtr = False  # applied as the port opens
            port.rts = False
        try:
            port.open()
        except (serial.SerialException, OSError) as exc:
            raise LinkError(self._explain_open_error(exc)) from exc
        except ValueError as exc:
            raise LinkError(f"{self.url}: the port rejects these settings: {exc}") from exc
        self._serial = port
        self._timeout = None
        fd = getattr(port, "fd", None) if _POSIX else None
        if isinstance(fd, int):
            self._fd = fd
            self._waker = Waker()
            self._poll = select.poll()
            self._poll.register(fd, select.POLLIN)
            self._poll.register(self._waker.fileno(), select.POLLIN)
            self._drained = False
        if self.low_latency:
            self._set_low_latency(port)
        if self.reset:
            self._pulse_reset(port)

    def _read(self, max_bytes: int, timeout: float | None) -> bytes:
        import serial

        if self._fd is not None:
            return self._read_fd(self._fd, max_bytes, timeout)
        port = self._require()
        try:
            if timeout != self._timeout:
                if _POSIX:
                    # pyserial's setter re-applies every termios setting (tcsetattr) on each
                    # change, and a reader loop changes the timeout on almost every call; on
                    # POSIX the timeout only feeds select(), so set it without reconfiguring.
                    port._timeout = timeout  # type: ignore[attr-defined]
                else:
                    port.timeout = timeout
                self._timeout = timeout
            data = port.read(1)
            if data and max_bytes > 1:
                waiting = port.in_waiting
                if waiting:
                    data += port.read(min(waiting, max_bytes - 1))
        except (serial.SerialException, OSError) as exc:
            raise self._gone(exc, "reading") from exc
        return bytes(data)

    def _read_fd(self, fd: int, max_bytes: int, timeout: float | None) -> bytes:
        """Read the port's descriptor: what is there now, else wait for it (POSIX).

        pyserial sets VMIN = VTIME = 0, so a read with nothing to read returns no bytes; no
        bytes right after poll() reported the port readable means the device hung up. A read
        that did not fill ``max_bytes`` drained the port, so the next one waits in poll()
        first instead of trying a read that would fail (a failed read raises and catches an
        exception: a reader that answers one frame at a time, a bridge's service calls, pays
        it on every call otherwise).
        """
        waker, poll = self._waker, self._poll
        if waker is None or poll is None:
            raise LinkClosedError(f"{self.url} is not open", local=True)
        wait_first = self._drained and timeout != 0
        end: float | None = None
        readable = False
        while True:
            if wait_first:
                wait_first = False
            else:
                try:
                    data = os.read(fd, max_bytes)
                except (BlockingIOError, InterruptedError):
                    data = b""
                except OSError as exc:
                    raise self._gone(exc, "reading") from exc
                if data:
                    self._drained = len(data) < max_bytes
                    return data
                if readable:
                    raise self._gone(
                        OSError(errno.EIO, "device reports readiness to read but returned no data"),
                        "reading",
                    )
            if waker.woken:
                return b""
            if timeout is None:
                wait_ms: float | None = None
            elif end is None:
                end = time.monotonic() + timeout
                wait_ms = timeout * 1000.0
            else:
                remaining = end - time.monotonic()
                if remaining <= 0.0:
                    return b""
                wait_ms = remaining * 1000.0
            readable = False
            for ready_fd, _ in poll.poll(wait_ms):
                if ready_fd == fd:
                    readable = True

    def _write(self, data: memoryview) -> None:
        import serial

        fd = self._fd
        if fd is not None and self._waker is not None:
            try:
                try:
                    sent = os.write(fd, data)  # the common case: the port's buffer has room
                except (BlockingIOError, InterruptedError):
                    sent = 0
                if sent < len(data):
                    write_all(
                        lambda view: os.write(fd, view),
                        fd,
                        data[sent:],
                        self._waker,
                        self.write_timeout,
                        self.url,
                    )
            except OSError as exc:
                raise self._gone(exc, "writing") from exc
            return
        port = self._require()
        try:
            written = port.write(data)
        except serial.SerialTimeoutException as exc:
            raise LinkError(
                f"write to {self.url} timed out after {self.write_timeout} s: the device does "
                "not take data (flow control, or a stalled board?)"
            ) from exc
        except (serial.SerialException, OSError) as exc:
            raise self._gone(exc, "writing") from exc
        if written is not None and written < len(data):
            if self._stopping:
                raise self._closed_error("write to")
            raise LinkError(f"write to {self.url} sent {written} of {len(data)} bytes")

    def _wake(self) -> None:
        if self._waker is not None:
            self._waker.wake()
        port = self._serial
        if port is not None:
            port.cancel_read()
            port.cancel_write()

    def _close(self) -> None:
        if self._waker is not None:
            self._waker.close()
        self._fd = self._waker = self._poll = None
        port, self._serial = self._serial, None
        if port is not None:
            port.close()

    # ------------------------------------------------------------------------------ internals

    def _require(self) -> serial.Serial:
        if self._serial is None:
            raise LinkClosedError(f"{self.url} is not open", local=True)
        return self._serial

    def _set_low_latency(self, port: serial.Serial) -> None:
        setter = getattr(port, "set_low_latency_mode", None)
        if setter is None:
            log.debug("%s: no low-latency mode on this platform", self.url)
            return
        try:
            setter(True)
        except (ValueError, OSError) as exc:  # ptys and many USB drivers do not support it
            log.debug("%s: low-latency mode not available: %s", self.url, exc)

    def _pulse_reset(self, port: serial.Serial) -> None:
        import serial

        try:
            port.dtr = False
            port.rts = False
            time.sleep(_RESET_PULSE)
            port.dtr = True
            port.rts = True
            port.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            log.warning("%s: reset=1 ignored, the port has no DTR/RTS lines: %s", self.url, exc)

    def _gone(self, exc: Exception, action: str) -> LinkError:
        """The error for a failed read or write: the port is gone, or some other failure."""
        code = getattr(exc, "errno", None)
        missing = os.name == "posix" and not Path(self.port).exists()
        vanished = (
            code in (errno.EIO, errno.ENXIO, errno.ENODEV, errno.EBADF)
            or "returned no data" in str(exc)
            or "[Errno 5]" in str(exc)
            or missing
        )
        if vanished:
            why = (
                "the device file is gone (unplugged?)"
                if missing
                else "the device stopped answering (unplugged, reset, or the other end of the pty "
                "closed)"
            )
            return LinkClosedError(
                f"serial port {self.port} failed while {action}: {why}; open() the link again "
                f"when the device is back ({exc})"
            )
        return LinkClosedError(f"serial port {self.port} failed while {action}: {exc}")

    def _explain_open_error(self, exc: Exception) -> str:
        code = getattr(exc, "errno", None)
        text = str(exc)
        port = self.port
        if code == errno.ENOENT or "FileNotFoundError" in text or "cannot find" in text:
            hints = []
            if os.name == "posix" and not port.startswith("/"):
                hints.append(f"serial URLs take an absolute path: serial:///dev/{port}")
            if ":" in port and not port.upper().startswith("COM"):
                hints.append(f"for a TCP address use socket://{port}")
            hints.append(_available_ports())
            return f"no serial port {port} ({self.url}): it does not exist; " + "; ".join(hints)
        if code in (errno.EACCES, errno.EPERM) or "PermissionError" in text:
            if sys.platform == "win32":
                return (
                    f"access denied to {port}: another program has it open (serial monitor, "
                    "another hwbridge); close it"
                )
            return (
                f"permission denied on {port}: {_group_hint(port)}, or run with access to the port"
            )
        if code in (errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK) or "lock" in text.lower():
            return (
                f"serial port {port} is busy: another program holds it (a serial monitor, "
                "ModemManager, another hwbridge); close that program, or pass exclusive=0 to "
                "share it (then both get only part of the bytes)"
            )
        return f"cannot open serial port {port} ({self.url}): {text}"


def _group_hint(port: str) -> str:
    """How to get access to ``port`` (the group that owns it, as on most Linux systems)."""
    group = "dialout"
    try:
        import grp

        group = grp.getgrgid(Path(port).stat().st_gid).gr_name
    except (ImportError, OSError, KeyError):
        pass
    return (
        f"add yourself to the '{group}' group (sudo usermod -aG {group} $USER, then log out and "
        "back in)"
    )


def _available_ports(limit: int = 8) -> str:
    """A short list of the serial ports pyserial sees, for error messages."""
    try:
        from serial.tools import list_ports

        found = sorted(list_ports.comports(), key=lambda info: info.device)
    except (ImportError, OSError) as exc:  # the listing is a hint; never fail because of it
        log.debug("listing serial ports failed: %s", exc)
        return "cannot list the available ports"
    if not found:
        return "no serial ports found (is the board plugged in?)"
    names = [
        f"{info.device} ({info.description})"
        if info.description and info.description != "n/a"
        else info.device
        for info in found[:limit]
    ]
    more = f" and {len(found) - limit} more" if len(found) > limit else ""
    return "available: " + ", ".join(names) + more
