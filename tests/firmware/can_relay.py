"""The far end of the HwBridge library's host-native CAN driver (``hwbridge/can/posix_driver.h``):
a TCP server that puts the frames a board program writes (one a line, ``1400007F#0102AB``) on a
python-can bus, and writes the bus's frames back to the program. Frames from the board's own
node id are not written back (udp_multicast echoes what a bus sends)."""

from __future__ import annotations

import socket
import threading
from typing import Any

import can

from hwbridge.protocols.can.transport import decode_id


def parse_line(line: str) -> can.Message | None:
    """A frame of the driver's line format, or None for anything else."""
    ident, sep, data = line.strip().partition("#")
    if not sep or len(ident) not in (3, 8):
        return None
    try:
        return can.Message(
            arbitration_id=int(ident, 16),
            is_extended_id=len(ident) == 8,
            data=bytes.fromhex(data),
        )
    except ValueError:
        return None


def format_line(message: Any) -> str:
    ident = (
        f"{message.arbitration_id:08X}"
        if message.is_extended_id
        else (f"{message.arbitration_id:03X}")
    )
    return f"{ident}#{bytes(message.data).hex().upper()}\n"


class CanRelay:
    """Serves one board program at a time on 127.0.0.1:``port`` (pick with port 0)."""

    def __init__(self, bus: Any, node: int) -> None:
        self.bus = bus
        self.node = node
        self.to_bus = 0
        self.from_bus = 0
        self.chained_to_bus = 0
        """Frames of chained transfers (CAN.md §12) the board sent."""
        self._server = socket.create_server(("127.0.0.1", 0))
        self._server.settimeout(0.1)
        self.port: int = self._server.getsockname()[1]
        self._client: socket.socket | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self._accept, daemon=True),
            threading.Thread(target=self._bus_to_board, daemon=True),
        ]
        for thread in self._threads:
            thread.start()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                client, _ = self._server.accept()
            except OSError:
                continue
            with self._lock:
                if self._client is not None:
                    self._client.close()
                self._client = client
            threading.Thread(target=self._board_to_bus, args=(client,), daemon=True).start()

    def _board_to_bus(self, client: socket.socket) -> None:
        with client, client.makefile("rb") as stream:
            try:
                for raw in stream:
                    message = parse_line(raw.decode("ascii", "replace"))
                    if message is not None:
                        self.bus.send(message)
                        self.to_bus += 1
                        ident = decode_id(message.arbitration_id)
                        if ident is not None and ident.chain:
                            self.chained_to_bus += 1
            except (OSError, ValueError):
                pass

    def _bus_to_board(self) -> None:
        while not self._stop.is_set():
            message = self.bus.recv(0.05)
            if message is None or message.is_error_frame:
                continue
            ident = decode_id(message.arbitration_id) if message.is_extended_id else None
            if ident is not None and ident.source == self.node:
                continue  # our board's own frames, echoed (either CAN.md format)
            with self._lock:
                client = self._client
            if client is None:
                continue
            try:
                client.sendall(format_line(message).encode("ascii"))
                self.from_bus += 1
            except OSError:
                with self._lock:
                    if self._client is client:
                        self._client = None

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(2)
        with self._lock:
            if self._client is not None:
                self._client.close()
                self._client = None
        self._server.close()
