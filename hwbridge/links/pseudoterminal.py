"""``pty://``: a new pseudo-terminal; the link is its master end, a board opens the slave.

An emulated board (or any program that talks to a serial port) opens :attr:`PtyLink.slave_path`
(``/dev/pts/N``) as if it were a serial port. The slave is in raw mode (8 bits, no echo, no CR/LF
translation, no signal characters), so every byte goes through unchanged.

Semantics, which the bridge can rely on (they mirror ``tcp-listen://``):

* ``open()`` creates the pty; it lives until ``close()`` (a reopen makes a new one, with a new
  ``slave_path``; the ``symlink=PATH`` option keeps a fixed name pointing at the current one).
* ``read()`` returns ``b""`` while no process has the slave open, and data once one does.
* When that process closes the slave (or exits), ``read()`` raises
  :class:`~hwbridge.links.base.LinkClosedError` once, after the bytes it wrote before leaving; the
  link stays open (``is_open`` stays True), unread bytes are discarded, and the next ``read()``
  waits for the next process to open ``slave_path``.
* ``write()`` raises ``LinkClosedError`` while no process has the slave open (bytes would otherwise
  wait in the pty for whoever opens it next).
* A process that opens and closes the slave between two reads without writing goes unnoticed.

POSIX only (tested on Linux).
"""

from __future__ import annotations

import errno
import logging
import os
import selectors
import sys
from pathlib import Path
from typing import Any, Final
from urllib.parse import urlsplit

from hwbridge.errors import LinkError
from hwbridge.links._io import Deadline, write_all
from hwbridge.links.base import (
    COMMON_OPTIONS,
    Link,
    LinkClosedError,
    OptionConverter,
    Waker,
    parse_options,
    split_query,
)

__all__ = ["PtyLink", "make_raw"]

log = logging.getLogger("hwbridge.links")

_OPTIONS: Final[dict[str, OptionConverter]] = {**COMMON_OPTIONS, "symlink": str}
_PEER_POLL: Final = 0.02
"""Seconds between checks for a process opening the slave (the pty cannot signal that)."""


def make_raw(fd: int) -> None:
    """Put the terminal ``fd`` in raw mode: 8 data bits, no echo, no translation, no signals."""
    import termios

    attrs = termios.tcgetattr(fd)
    attrs[0] &= ~(
        termios.IGNBRK
        | termios.BRKINT
        | termios.PARMRK
        | termios.ISTRIP
        | termios.INLCR
        | termios.IGNCR
        | termios.ICRNL
        | termios.IXON
        | termios.IXOFF
        | termios.IXANY
        | termios.INPCK
    )
    attrs[1] &= ~termios.OPOST
    attrs[2] &= ~(termios.CSIZE | termios.PARENB)
    attrs[2] |= termios.CS8
    attrs[3] &= ~(termios.ECHO | termios.ECHONL | termios.ICANON | termios.ISIG | termios.IEXTEN)
    attrs[6][termios.VMIN] = 1
    attrs[6][termios.VTIME] = 0
    termios.tcsetattr(fd, termios.TCSANOW, attrs)


class PtyLink(Link):
    """The master end of a new pseudo-terminal; see the module documentation.

    Options: ``symlink`` (a path to point at the slave while open, like socat's ``link=``),
    ``write_timeout`` (seconds; default none: wait while the board does not read).
    """

    scheme = "pty"

    def __init__(self, url: str, **options: Any) -> None:
        super().__init__(url)
        parts = urlsplit(url)
        if parts.netloc or parts.path not in ("", "/"):
            raise LinkError(
                f"{url!r}: pty:// creates a new pseudo-terminal and takes no path; to open an "
                f"existing one use serial://{parts.netloc}{parts.path} or the bare path"
            )
        opts = parse_options(url, _OPTIONS, split_query(parts.query, url), options)
        symlink = opts.get("symlink")
        self.symlink: Path | None = Path(symlink) if symlink else None
        self.write_timeout: float | None = opts.get("write_timeout")
        self._master: int | None = None
        self._slave_path: str | None = None
        self._waker: Waker | None = None
        self._selector: selectors.BaseSelector | None = None
        self._idle: selectors.BaseSelector | None = None  # the waker alone
        self._peer_seen = False

    @property
    def slave_path(self) -> str | None:
        """The path a board opens as its serial port (``/dev/pts/N``); None when closed."""
        return self._slave_path

    @property
    def connected(self) -> bool:
        """True while some process has the slave open."""
        master = self._master
        return self.is_open and master is not None and self._peer_attached(master)

    def _open(self) -> None:
        if sys.platform == "win32":
            raise LinkError(
                "pty:// needs a POSIX system (Linux, macOS); on Windows use a virtual COM port "
                "pair (com0com) with serial://, or memory:// inside one process"
            )
        try:
            master, slave = os.openpty()
        except OSError as exc:
            raise LinkError(
                f"cannot create a pseudo-terminal for {self.url}: {exc.strerror or exc}; too many "
                "open ptys? (see /proc/sys/kernel/pty/max)"
            ) from exc
        import termios

        try:
            make_raw(slave)
            slave_path = os.ttyname(slave)
            os.set_blocking(master, False)
            if self.symlink is not None:
                self._make_symlink(slave_path)
        except (OSError, LinkError, termios.error) as exc:
            os.close(master)
            if isinstance(exc, LinkError):
                raise
            raise LinkError(f"cannot set up the pseudo-terminal for {self.url}: {exc}") from exc
        finally:
            # Keep no slave descriptor: the master reads EIO (and polls HUP) exactly while no
            # process has the slave open, which is how peers coming and going are seen. Raw
            # settings stay with the pty until the master closes.
            os.close(slave)
        self._master = master
        self._slave_path = slave_path
        self._waker = Waker()
        self._selector = selectors.DefaultSelector()
        self._selector.register(master, selectors.EVENT_READ)
        self._selector.register(self._waker, selectors.EVENT_READ)
        self._idle = selectors.DefaultSelector()
        self._idle.register(self._waker, selectors.EVENT_READ)
        self._peer_seen = False
        log.info("%s: pseudo-terminal ready at %s", self.url, slave_path)

    def _make_symlink(self, target: str) -> None:
        assert self.symlink is not None
        link = self.symlink
        if link.exists() and not link.is_symlink():
            raise LinkError(
                f"cannot make the symlink {link} for {self.url}: a file that is not a symlink is "
                "there; remove it or choose another path"
            )
        temporary = link.with_name(f".{link.name}.{os.getpid()}.tmp")
        try:
            temporary.unlink(missing_ok=True)
            temporary.symlink_to(target)
            temporary.replace(link)
        except OSError as exc:
            raise LinkError(
                f"cannot make the symlink {link} -> {target} for {self.url}: "
                f"{exc.strerror or exc}; check that its folder exists and is writable"
            ) from exc

    def _read(self, max_bytes: int, timeout: float | None) -> bytes:
        master, waker, selector, idle = self._parts()
        deadline = Deadline(timeout)
        while True:
            try:
                data = os.read(master, max_bytes)
            except (BlockingIOError, InterruptedError):  # a peer is there, nothing to read
                self._peer_seen = True
                if waker.woken:
                    return b""
                if not selector.select(deadline.remaining()) and deadline.expired():
                    return b""
                continue
            except OSError as exc:
                if exc.errno != errno.EIO:
                    raise LinkError(f"read from {self.url} failed: {exc}") from exc
                data = b""  # EIO: no process has the slave open (any more)
            if data:
                self._peer_seen = True
                return data
            if self._peer_seen:
                self._peer_seen = False
                self._discard_buffers(master)
                raise LinkClosedError(
                    f"the program using {self._slave_path} ({self.url}) closed it; waiting for "
                    "the next one to open it"
                )
            if waker.woken or deadline.expired():
                return b""
            remaining = deadline.remaining()
            idle.select(_PEER_POLL if remaining is None else min(_PEER_POLL, remaining))

    def _write(self, data: memoryview) -> None:
        master, waker, _, _ = self._parts()
        if not self._peer_attached(master):
            raise LinkClosedError(
                f"no program has {self._slave_path} open ({self.url}); writes wait for one"
            )
        try:
            write_all(
                lambda view: os.write(master, view),
                master,
                data,
                waker,
                self.write_timeout,
                self.url,
            )
        except OSError as exc:
            if exc.errno == errno.EIO:
                raise LinkClosedError(
                    f"the program using {self._slave_path} closed it while {self.url} was writing"
                ) from exc
            raise LinkError(f"write to {self.url} failed: {exc}") from exc

    @staticmethod
    def _peer_attached(master: int) -> bool:
        """Whether a process has the slave open (the master polls HUP while none does)."""
        import select

        poller = select.poll()
        poller.register(master, select.POLLOUT)
        return not any(event & select.POLLHUP for _, event in poller.poll(0))

    @staticmethod
    def _discard_buffers(master: int) -> None:
        import termios

        try:
            termios.tcflush(master, termios.TCIOFLUSH)
        except OSError as exc:
            log.debug("flushing the pty failed: %s", exc)

    def _survives_peer_loss(self) -> bool:
        return True

    def _wake(self) -> None:
        if self._waker is not None:
            self._waker.wake()

    def _close(self) -> None:
        for selector in (self._selector, self._idle):
            if selector is not None:
                selector.close()
        if self._waker is not None:
            self._waker.close()
        if self._master is not None:
            os.close(self._master)
        if self.symlink is not None and self._slave_path is not None:
            try:
                if self.symlink.is_symlink() and str(self.symlink.readlink()) == self._slave_path:
                    self.symlink.unlink()
            except OSError as exc:
                log.debug("removing the symlink %s failed: %s", self.symlink, exc)
        self._master = None
        self._slave_path = None
        self._waker = self._selector = self._idle = None

    def _parts(
        self,
    ) -> tuple[int, Waker, selectors.BaseSelector, selectors.BaseSelector]:
        if (
            self._master is None
            or self._waker is None
            or self._selector is None
            or self._idle is None
        ):
            raise LinkClosedError(f"{self.url} is not open", local=True)
        return self._master, self._waker, self._selector, self._idle
