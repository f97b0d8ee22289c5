"""Device-side test boards: real protocol sessions on a real pseudo-terminal.

A :class:`PtyBoard` runs a device session (the rosserial client emulation, later native device
sessions) in a :class:`~hwbridge.pump.SessionPump` on the master end of a ``pty://`` link whose
slave is reachable at a fixed symlink, so a bridge in another process can open it like a serial
port, and the board can be killed and started again at the same path.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hwbridge import msg
from hwbridge.links import open_link
from hwbridge.protocols.rosserial import RosserialDevice
from hwbridge.pump import SansIOSession, SessionPump


class PtyBoard:
    """A device session on a pty at ``path``; ``events`` collects what the session reports."""

    def __init__(self, path: Path, session: SansIOSession, name: str = "board") -> None:
        self.path = path
        self.session = session
        self.events: list[Any] = []
        self.link = open_link(f"pty://?symlink={path}")
        self.pump = SessionPump(self.link, session, self.events.append, name=f"device-{name}")
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    def start(self) -> PtyBoard:
        self.pump.start()
        return self

    def every(self, period: float, action: Callable[[Any], object]) -> None:
        """Run ``action(session)`` every ``period`` seconds (under the pump's lock)."""

        def loop() -> None:
            while not self._stop.wait(period):
                if self.pump.running:
                    try:
                        self.pump.call(action)
                    except Exception:  # noqa: BLE001 - the link may close under us in a test
                        return

        thread = threading.Thread(target=loop, daemon=True)
        thread.start()
        self._threads.append(thread)

    def of_type(self, name: str) -> list[Any]:
        return [e for e in list(self.events) if type(e).__name__ == name]

    def stop(self) -> None:
        """Power off: the pty goes away (the bridge sees the port vanish)."""
        self._stop.set()
        self.pump.stop()
        self.link.close()
        for thread in self._threads:
            thread.join(2)


def rosserial_sketch() -> RosserialDevice:
    """A typical rosserial sketch: chatter publisher, led subscriber, a reset service."""
    device = RosserialDevice(msg.registry())
    device.advertise("chatter", "std_msgs/String")
    device.subscribe("led", "std_msgs/Bool")
    device.advertise_service(
        "reset",
        "std_srvs/Trigger",
        lambda _req: msg.encode(msg.new("std_srvs/TriggerResponse", success=True, message="done")),
    )
    return device


def chatter(count: list[int]) -> Callable[[RosserialDevice], object]:
    """An action publishing ``hello N`` on chatter."""

    def publish(device: RosserialDevice) -> object:
        count[0] += 1
        return device.publish(
            "chatter", msg.encode(msg.new("std_msgs/String", data=f"hello {count[0]}"))
        )

    return publish


def wait_for(condition: Callable[[], bool], timeout: float = 15.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return condition()
