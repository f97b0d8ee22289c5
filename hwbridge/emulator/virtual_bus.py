"""python-can's ``virtual`` bus for emulated boards, copying each frame once for all receivers
and filtering it as a controller's acceptance filters do (see :func:`shared_virtual_bus`)."""

from __future__ import annotations

import queue
import threading
import time
import weakref
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["Relay", "shared_virtual_bus"]

_R = TypeVar("_R", bound="Relay")


class Relay:
    """Threads that carry frames between an emulated bus and something else (a pty, a
    multicast group) until :meth:`stop`; a context manager."""

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    def start(self: _R) -> _R:
        raise NotImplementedError

    def stop(self) -> None:
        raise NotImplementedError

    def _spawn(self, *loops: tuple[Callable[[], None], str]) -> None:
        for target, name in loops:
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)

    def _join(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(2)

    def __enter__(self: _R) -> _R:
        return self.start()

    def __exit__(self, *_exc: object) -> None:
        self.stop()


_shared_bus_class: Any = None


def shared_virtual_bus(channel: str, **kwargs: Any) -> Any:
    """A python-can ``virtual`` bus on ``channel`` for an emulated board: on the same channel as
    any ``can.Bus(interface="virtual", channel=...)`` (the host's ``can://virtual/...`` links
    among them), but each frame it sends is copied once for all the other buses instead of
    deep-copied for each of them.

    Why: python-can's virtual bus deep-copies every frame for every other bus on the channel
    (about 50 us a copy here), so with eight emulated boards and the host in one process, eight
    copies of each frame were 57 % of the process's CPU (py-spy, sampling the thread holding
    the GIL); the host's CAN reader, on the same GIL, then fell behind until its backlog of
    frames outgrew the native link timeout (0.8 s) and sessions were dropped on a busy machine.
    A real bus copies frames in hardware. Receivers only read the frames they get."""
    global _shared_bus_class  # noqa: PLW0603 - made once, when python-can is first needed
    if _shared_bus_class is None:
        import can
        from can.interfaces.virtual import VirtualBus

        wanted: weakref.WeakKeyDictionary[Any, Any] = weakref.WeakKeyDictionary()
        """Each shared-copy bus's receive queue -> its filters (None: everything)."""

        class SharedCopyVirtualBus(VirtualBus):
            def __init__(self, **options: Any) -> None:
                super().__init__(**options)
                wanted[self.queue] = self._filters

            def _apply_filters(self, filters: Any) -> None:
                # Shared-copy senders filter as they hand frames out, as a controller's
                # acceptance filters do, so a board never wakes for other boards' frames;
                # python-can filters what plain virtual buses send when it is received.
                receive = getattr(self, "queue", None)  # None while BusABC's __init__ runs
                if receive is not None:
                    wanted[receive] = filters

            def send(self, msg: Any, timeout: float | None = None) -> None:
                self._check_if_open()
                copy = can.Message(
                    timestamp=msg.timestamp if self.preserve_timestamps else time.time(),
                    arbitration_id=msg.arbitration_id,
                    is_extended_id=msg.is_extended_id,
                    is_remote_frame=msg.is_remote_frame,
                    is_error_frame=msg.is_error_frame,
                    channel=self.channel_id,
                    dlc=msg.dlc,
                    data=bytes(msg.data),
                    is_fd=msg.is_fd,
                    is_rx=True,
                    bitrate_switch=msg.bitrate_switch,
                    error_state_indicator=msg.error_state_indicator,
                )
                full = False
                for receiver in list(self.channel):
                    if receiver is self.queue or not _passes(copy, wanted.get(receiver)):
                        continue
                    try:
                        receiver.put(copy, block=True, timeout=timeout)
                    except queue.Full:
                        full = True
                if full:
                    raise can.CanOperationError("a receiver's queue on the virtual bus is full")

        _shared_bus_class = SharedCopyVirtualBus
    return _shared_bus_class(channel=channel, **kwargs)


def _passes(message: Any, filters: Any) -> bool:
    """Whether ``message`` passes python-can ``can_filters`` (None or empty: everything)."""
    if not filters:
        return True
    for item in filters:
        if "extended" in item and item["extended"] != message.is_extended_id:
            continue
        if (message.arbitration_id ^ item["can_id"]) & item["can_mask"] == 0:
            return True
    return False
