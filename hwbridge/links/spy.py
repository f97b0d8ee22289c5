"""``spy+URL``: wrap any link and hex-dump every byte read and written (like pyserial's spy://).

``spy+serial:///dev/ttyACM0`` behaves as ``serial:///dev/ttyACM0`` and logs each chunk to the
``hwbridge.links.spy`` logger (level INFO), or to a file with ``spy_file=PATH`` (query or keyword;
``-`` is stderr; a keyword may also be an open text stream). The other options go to the wrapped
link. A dump looks like::

    # 2025-01-31T10:00:00.123 open serial:///dev/ttyACM0
      0.012345 TX 00000000  ff fe 00 00 01 02 03 04  05 06 07 08 09 0a 0b 0c |................|
      0.013001 RX 00000000  68 65 6c 6c 6f 0d 0a                             |hello..|
    # 0.020000 close

Columns: seconds since the link opened, direction (TX: written by the host, RX: read by the
host), offset of the first byte in that direction since open, 16 bytes in hex, then as ASCII.
"""

from __future__ import annotations

import datetime
import logging
import os
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Final, TextIO
from urllib.parse import parse_qsl, urlencode

from hwbridge.errors import LinkError
from hwbridge.links.base import Link, closest

__all__ = ["SPY_LOGGER", "SpyLink", "hexdump"]

SPY_LOGGER: Final = "hwbridge.links.spy"
_SPY_OPTIONS: Final = ("spy_file",)
_WIDTH: Final = 16

spy_log = logging.getLogger(SPY_LOGGER)


def hexdump(data: bytes, offset: int = 0) -> Iterator[str]:
    """Lines of ``offset  hex  |ascii|`` for ``data``, 16 bytes a line."""
    for start in range(0, len(data), _WIDTH):
        chunk = data[start : start + _WIDTH]
        left = " ".join(f"{b:02x}" for b in chunk[:8])
        right = " ".join(f"{b:02x}" for b in chunk[8:])
        hex_column = f"{left}  {right}" if right else left
        text = "".join(chr(b) if 32 <= b < 127 else "." for b in chunk)
        yield f"{offset + start:08x}  {hex_column:<{_WIDTH * 3}} |{text}|"


def _split_spy_options(url: str) -> tuple[str, dict[str, str]]:
    """Take the ``spy_*`` options out of ``url``'s query; returns the rest of the URL and them."""
    base, sep, query = url.partition("?")
    if not sep:
        return url, {}
    spy: dict[str, str] = {}
    rest: list[tuple[str, str]] = []
    for key, value in parse_qsl(query, keep_blank_values=True):
        name = key.strip().lower()
        if name.startswith("spy_"):
            if name not in _SPY_OPTIONS:
                hint = closest(name, _SPY_OPTIONS)
                raise LinkError(
                    f"unknown spy option {name!r} in {url!r}"
                    + (f"; did you mean {hint!r}?" if hint else f" (spy takes {_SPY_OPTIONS})")
                )
            spy[name] = value
        else:
            rest.append((key, value))
    return (f"{base}?{urlencode(rest)}" if rest else base), spy


class SpyLink(Link):
    """Any link, with a hex dump of its traffic; :attr:`inner` is the wrapped link."""

    scheme = "spy"

    def __init__(self, url: str, **options: Any) -> None:
        from hwbridge.links.registry import create_link

        super().__init__(url)
        _, _, inner_url = url.partition("+")
        if not inner_url:
            raise LinkError(
                f"{url!r} wraps nothing: write spy+ before another link URL, as in "
                "spy+serial:///dev/ttyACM0 or spy+socket://192.168.4.1:11411"
            )
        inner_url, spy_options = _split_spy_options(inner_url)
        self.spy_file: str | os.PathLike[str] | TextIO | None = options.pop(
            "spy_file", spy_options.get("spy_file") or None
        )
        self.inner: Link = create_link(inner_url, **options)
        self._out: TextIO | None = None
        self._owns_out = False
        self._spy_lock = threading.Lock()
        self._started = time.monotonic()
        self._offsets = {"RX": 0, "TX": 0}

    @property
    def connected(self) -> bool:
        """Whether the wrapped link has a peer."""
        return self.is_open and self.inner.connected

    # ---------------------------------------------------------------------------------- hooks

    def _open(self) -> None:
        self._open_output()
        try:
            self.inner.open()
        except LinkError as exc:
            self._event(f"open failed: {exc}")
            self._close_output()
            raise
        self._started = time.monotonic()
        self._offsets = {"RX": 0, "TX": 0}
        now = datetime.datetime.now().isoformat(timespec="milliseconds")
        self._emit([f"# {now} open {self.inner.url}"])

    def _read(self, max_bytes: int, timeout: float | None) -> bytes:
        try:
            data = self.inner.read(max_bytes, timeout)
        except LinkError as exc:
            self._event(f"read: {type(exc).__name__}: {exc}")
            raise
        if data:
            self._dump("RX", data)
        return data

    def _write(self, data: memoryview) -> None:
        try:
            self.inner.write(data)
        except LinkError as exc:
            self._event(f"write of {len(data)} bytes: {type(exc).__name__}: {exc}")
            raise
        self._dump("TX", data.tobytes())

    def _wake(self) -> None:
        self.inner.close()  # returns once the inner link's blocked I/O has returned

    def _close(self) -> None:
        self.inner.close()
        self._event("close")
        self._close_output()

    def _survives_peer_loss(self) -> bool:
        return self.inner.is_open

    # ------------------------------------------------------------------------------ internals

    def _open_output(self) -> None:
        target = self.spy_file
        if target is None:
            return
        if isinstance(target, (str, os.PathLike)):
            if os.fspath(target) == "-":
                self._out, self._owns_out = sys.stderr, False
                return
            try:
                self._out = Path(target).open("a", encoding="utf-8")  # noqa: SIM115 (kept open)
            except OSError as exc:
                raise LinkError(
                    f"cannot open the spy file {os.fspath(target)!r} for {self.url}: "
                    f"{exc.strerror or exc}; check the folder exists and is writable"
                ) from exc
            self._owns_out = True
        else:
            self._out, self._owns_out = target, False

    def _close_output(self) -> None:
        with self._spy_lock:
            out, self._out = self._out, None
            if out is not None and self._owns_out:
                out.close()

    def _dump(self, direction: str, data: bytes) -> None:
        elapsed = time.monotonic() - self._started
        with self._spy_lock:
            offset = self._offsets[direction]
            self._offsets[direction] = offset + len(data)
        stamp = f"{elapsed:10.6f} {direction} "
        self._emit([stamp + line for line in hexdump(data, offset)])

    def _event(self, text: str) -> None:
        self._emit([f"# {time.monotonic() - self._started:.6f} {text}"])

    def _emit(self, lines: list[str]) -> None:
        with self._spy_lock:
            out = self._out
            if out is not None:
                out.write("".join(f"{line}\n" for line in lines))
                out.flush()
                return
        for line in lines:
            spy_log.info("%s %s", self.inner.url, line)
