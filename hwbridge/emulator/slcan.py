"""An emulated SLCAN adapter (a CANable, a Lawicel CAN232) on a pseudo-terminal.

The adapter's serial side is a pty (``adapter.path``) that python-can's own ``slcan`` interface
opens unmodified (``can.Bus(interface="slcan", channel=path, sleep_after_open=0)``, or the link
``can://slcan/dev/pts/N/node1?sleep_after_open=0``); its CAN side is a python-can bus (by
default the in-process ``virtual`` channel given), where emulated boards sit. Lines are ASCII
ended by CR; what it understands:

=========================  =====================================================================
``O`` / ``L`` / ``C``      open the channel (``L``: listen only) / close it
``S0``..``S8``, ``Yn``,    bit rates (10 kbit/s .. 1 Mbit/s; CAN FD data rate), ``sXXYY`` BTR
``sXXYY``
``tIIILDD..``              a standard frame (3 hex id digits, length, data); ``T`` extended
                           (8 digits); ``r``/``R`` remote frames; ``d``/``D`` CAN FD and
                           ``b``/``B`` CAN FD with bit-rate switch (the length is a DLC code)
``V``, ``v``, ``N``, ``F`` versions, serial number, status flags; ``Z0``/``Z1`` timestamps
                           (accepted, never added)
=========================  =====================================================================

Each command is answered with CR (``z``/``Z`` CR for a sent frame, as Lawicel adapters do) or
BEL for one refused: malformed, a frame while closed or listening only, a bit rate while open.
Frames from the bus are written as ``T``/``t``/``D``/``d`` lines while the channel is open.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import threading
import tty
from typing import Any, Final

from hwbridge.emulator.virtual_bus import Relay, shared_virtual_bus

__all__ = ["SlcanAdapter"]

log = logging.getLogger("hwbridge.emulator.slcan")

_OK: Final = b"\r"
_BELL: Final = b"\a"
_FD_DLC: Final = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
_MAX_LINE: Final = 200


def _dlc_of(length: int) -> int:
    return _FD_DLC.index(length)


class SlcanAdapter(Relay):
    """An SLCAN adapter on a new pty, bridged to the python-can bus ``channel`` of
    ``interface`` (see the module docstring)."""

    def __init__(self, channel: str, interface: str = "virtual") -> None:
        super().__init__()
        self.channel = channel
        self.interface = interface
        self.path = ""
        self.is_open = False
        self.listen_only = False
        self.bitrate: int | None = None
        self.frames_to_bus = 0
        self.frames_to_host = 0
        self.fd_frames = 0
        """CAN FD frames among those the host sent."""
        self.refused = 0
        """Commands answered with BEL."""
        self._master = -1
        self._slave = -1
        self._bus: Any = None
        self._write_lock = threading.Lock()

    def start(self) -> SlcanAdapter:
        import can

        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        if self.interface == "virtual":
            # frames from the host are copied once for all the boards, and only to the boards
            # whose filters take them (python-can's virtual bus deep-copies one per board)
            self._bus = shared_virtual_bus(self.channel)
        else:
            self._bus = can.Bus(interface=self.interface, channel=self.channel)
        self._spawn((self._serial_loop, "slcan-serial"), (self._bus_loop, "slcan-bus"))
        return self

    def stop(self) -> None:
        self._join()
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None
        for fd in (self._master, self._slave):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = -1

    # ------------------------------------------------------------------ serial side
    def _send_host(self, data: bytes) -> None:
        with self._write_lock:
            view = memoryview(data)
            while view and not self._stop.is_set():
                try:
                    written = os.write(self._master, view)
                except BlockingIOError:
                    select.select([], [self._master], [], 0.05)
                    continue
                except OSError:
                    return
                view = view[written:]

    def _serial_loop(self) -> None:
        buffer = bytearray()
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master], [], [], 0.05)
            if not ready:
                continue
            try:
                chunk = os.read(self._master, 4096)
            except OSError:
                self._stop.wait(0.05)  # nobody has the port open: wait for one
                continue
            buffer += chunk
            while True:
                end = buffer.find(b"\r")
                if end < 0:
                    if len(buffer) > _MAX_LINE:
                        buffer.clear()
                        self.refused += 1
                        self._send_host(_BELL)
                    break
                line, buffer = bytes(buffer[:end]), buffer[end + 1 :]
                self._send_host(self._command(line.decode("ascii", "replace").strip("\n")))

    def _command(self, line: str) -> bytes:
        """The answer to one command line (without its CR)."""
        if not line:
            return _OK
        op, arg = line[0], line[1:]
        if op in "tTrRdDbB":
            return self._frame(op, arg)
        answer: bytes | None = None
        if op in "OL" and not arg:
            self.is_open, self.listen_only = True, op == "L"
            answer = _OK
        elif op == "C" and not arg:
            self.is_open = False
            answer = _OK
        elif op == "S" and len(arg) == 1 and arg in "012345678" and not self.is_open:
            self.bitrate = (10, 20, 50, 100, 125, 250, 500, 750, 1000)[int(arg)] * 1000
            answer = _OK
        elif (op == "Y" and len(arg) == 1) or (op == "s" and len(arg) == 4):
            answer = _OK if not self.is_open else None
        elif op in "Vv" and not arg:
            answer = f"{op}1013\r".encode()
        elif op == "N" and not arg:
            answer = b"NHWB1\r"
        elif op == "F" and not arg:
            answer = b"F00\r"
        elif op == "Z" and arg in ("0", "1"):
            answer = _OK
        if answer is None:
            self.refused += 1
            return _BELL
        return answer

    def _frame(self, op: str, arg: str) -> bytes:
        import can

        extended = op in "TRDB"
        digits = 8 if extended else 3
        fd = op in "dDbB"
        remote = op in "rR"
        try:
            can_id = int(arg[:digits], 16)
            code = int(arg[digits], 16)
            length = _FD_DLC[code] if fd else code
            if (not fd and code > 8) or len(arg[:digits]) != digits:
                raise ValueError(arg)
            hex_data = arg[digits + 1 :]
            data = b"" if remote else bytes.fromhex(hex_data)
            if not remote and len(data) != length:
                raise ValueError(arg)
            if can_id >= (1 << 29 if extended else 1 << 11):
                raise ValueError(arg)
        except (ValueError, IndexError):
            self.refused += 1
            return _BELL
        if not self.is_open or self.listen_only or self._bus is None:
            self.refused += 1
            return _BELL
        message = can.Message(
            arbitration_id=can_id,
            is_extended_id=extended,
            is_remote_frame=remote,
            is_fd=fd,
            bitrate_switch=op in "bB",
            dlc=length,
            data=data,
        )
        try:
            self._bus.send(message)
        except can.CanError:
            self.refused += 1
            return _BELL
        self.frames_to_bus += 1
        self.fd_frames += fd
        return b"Z\r" if extended else b"z\r"

    # ------------------------------------------------------------------ bus side
    def _bus_loop(self) -> None:
        while not self._stop.is_set():
            bus = self._bus
            if bus is None:
                return
            message = bus.recv(0.05)
            if message is None or not self.is_open or message.is_error_frame:
                continue
            self._send_host(self._line(message))
            self.frames_to_host += 1

    @staticmethod
    def _line(message: Any) -> bytes:
        data = bytes(message.data)
        if message.is_fd:
            op = ("B" if message.bitrate_switch else "D") if message.is_extended_id else "d"
            length = f"{_dlc_of(len(data)):X}"
        else:
            op = "R" if message.is_remote_frame else "T"
            if not message.is_extended_id:
                op = op.lower()
            length = str(message.dlc if message.is_remote_frame else len(data))
        ident = (
            f"{message.arbitration_id:08X}"
            if message.is_extended_id
            else f"{message.arbitration_id:03X}"
        )
        payload = "" if message.is_remote_frame else data.hex().upper()
        return f"{op}{ident}{length}{payload}\r".encode()
