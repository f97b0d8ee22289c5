"""Device-side test boards: real protocol sessions on a real pseudo-terminal.

A :class:`PtyBoard` runs a device session (the rosserial client emulation, later native device
sessions) in a :class:`~hwbridge.pump.SessionPump` on the master end of a ``pty://`` link whose
slave is reachable at a fixed symlink, so a bridge in another process can open it like a serial
port, and the board can be killed and started again at the same path.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hwbridge import msg
from hwbridge.links import open_link
from hwbridge.protocols.rosserial import RosserialDevice
from hwbridge.pump import SansIOSession, SessionPump
from tests.netutil import wait_until


class PtyBoard:
    """A device session on a pty at ``path``; ``events`` collects what the session reports."""

    def __init__(
        self,
        path: Path,
        session: SansIOSession,
        name: str = "board",
        on_event: Callable[[PtyBoard, Any], None] | None = None,
    ) -> None:
        self.path = path
        self.session = session
        self.events: list[Any] = []
        self._on_event = on_event
        self.link = open_link(f"pty://?symlink={path}")
        self.pump = SessionPump(self.link, session, self._record, name=f"device-{name}")
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    def _record(self, event: Any) -> None:
        self.events.append(event)
        if self._on_event is not None:
            self._on_event(self, event)

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
    """:func:`tests.netutil.wait_until` with this module's longer default and coarser step."""
    return wait_until(condition, timeout, step=0.02)


def native_sketch(name: str = "uno") -> Any:
    """A native-protocol board: chatter publisher, led subscriber, a reset service server."""
    from hwbridge.protocols.native import session as ns
    from hwbridge.protocols.native.control import EntryKind

    registry = msg.registry()
    topics = [
        ns.TopicEntry(
            1, EntryKind.PUBLISHER, "chatter", "std_msgs/String", registry.md5("std_msgs/String")
        ),
        ns.TopicEntry(
            2, EntryKind.SUBSCRIBER, "led", "std_msgs/Bool", registry.md5("std_msgs/Bool")
        ),
        ns.TopicEntry(
            3,
            EntryKind.SERVICE_SERVER,
            "reset",
            "std_srvs/Trigger",
            registry.service("std_srvs/Trigger").md5,
        ),
    ]
    return ns.DeviceSession(ns.BoardInfo(name, b"\x00\x01", "0.1.0"), topics)


def answer_services(board: PtyBoard, event: Any) -> None:
    """An ``on_event`` for native boards: answer std_srvs/Trigger calls with success."""
    from hwbridge.protocols.native import session as ns

    if isinstance(event, ns.ServiceRequest):
        reply = msg.encode(msg.new("std_srvs/TriggerResponse", success=True, message="done"))
        board.pump.call(lambda s: s.respond_service(event.channel, event.request_id, reply))


def native_chatter(count: list[int]) -> Callable[[Any], object]:
    def publish(device: Any) -> object:
        count[0] += 1
        return device.publish(1, msg.encode(msg.new("std_msgs/String", data=f"hello {count[0]}")))

    return publish
