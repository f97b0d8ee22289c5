"""The soak bench's Python boards (``soak.py --boards-kind python``): board and topic names,
native-protocol device sessions on ``tcp-listen://`` links, and the emulator process that runs
several of them and answers commands on stdin (status, go, stop, quit)."""

from __future__ import annotations

import json
import sys
import threading
import time
from typing import Any


def board_name(index: int) -> str:
    return f"b{index:02d}"


def topic_name(index: int, topic: int) -> str:
    return f"/soak/{board_name(index)}/t{topic}"


class _Board:
    """One native board: a device session in a pump on a tcp-listen link."""

    def __init__(self, index: int, port: int, topics: int, reliable: int) -> None:
        from hwbridge import msg
        from hwbridge.links import open_link
        from hwbridge.protocols.native import session as ns
        from hwbridge.protocols.native.control import EntryKind
        from hwbridge.pump import SessionPump

        registry = msg.registry()
        string_md5 = registry.md5("std_msgs/String")
        entries = [
            ns.TopicEntry(
                1 + j,
                EntryKind.PUBLISHER,
                topic_name(index, j)[1:],
                "std_msgs/String",
                string_md5,
                reliable=j < reliable,
            )
            for j in range(topics)
        ]
        self.service_channel = topics + 1
        entries.append(
            ns.TopicEntry(
                self.service_channel,
                EntryKind.SERVICE_SERVER,
                f"soak/{board_name(index)}/trigger",
                "std_srvs/Trigger",
                registry.service("std_srvs/Trigger").md5,
            )
        )
        self.answer = msg.encode(msg.new("std_srvs/TriggerResponse", success=True, message="ok"))
        session = ns.DeviceSession(
            ns.BoardInfo(board_name(index), index.to_bytes(4, "little"), "soak"), entries
        )
        self.topics = topics
        self.seq = [0] * topics
        self.published = [0] * topics
        self.refused = [0] * topics
        self.served = 0
        self.link = open_link(f"tcp-listen://127.0.0.1:{port}")
        self.pump = SessionPump(self.link, session, self._on_event, name=board_name(index))
        self.pump.start()

    def _on_event(self, event: Any) -> None:
        from hwbridge.protocols.native import session as ns

        if isinstance(event, ns.ServiceRequest):
            self.served += 1
            answer = self.answer
            self.pump.call(lambda s: s.respond_service(event.channel, event.request_id, answer))

    def connected(self) -> bool:
        return bool(self.pump.call(lambda s: s.connected))

    def session_ends(self) -> dict[str, int]:
        """How often this board's session ended and started again (a reset loses what its
        reliable queue held): link losses, peer resets, sessions established."""
        stats = self.pump.call(lambda s: s.stats)
        return {
            "link_losses": int(stats.link_losses),
            "peer_resets": int(stats.peer_resets),
            "sessions": int(stats.sessions),
        }

    def publish_all(self, session: Any) -> None:
        """Under the pump's lock: one message on each topic."""
        seq, published, refused = self.seq, self.published, self.refused
        for j in range(self.topics):
            data = f"{seq[j]} {time.monotonic_ns()}".encode()
            payload = len(data).to_bytes(4, "little") + data
            if session.publish(1 + j, payload):
                published[j] += 1
                seq[j] += 1
            else:
                refused[j] += 1

    def close(self) -> None:
        self.pump.stop()
        self.link.close()


def emulator_main(first: int, ports: list[int], topics: int, rate: float, reliable: int) -> None:
    """Emulator process: boards listening on ``ports``; commands on stdin (status, go, stop)."""
    boards = [_Board(first + i, port, topics, reliable) for i, port in enumerate(ports)]
    running = threading.Event()
    finished = threading.Event()
    late = [0]

    def publisher() -> None:
        period = 1.0 / rate
        running.wait()
        next_tick = time.monotonic()
        while running.is_set():
            for board in boards:
                try:
                    board.pump.call(board.publish_all)
                except Exception:  # noqa: BLE001 - a board whose link dropped: count as refused
                    for j in range(topics):
                        board.refused[j] += 1
            next_tick += period
            delay = next_tick - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -period:  # a whole period behind: the process cannot keep the rate
                late[0] += 1
                next_tick = time.monotonic()
        finished.set()

    thread = threading.Thread(target=publisher, daemon=True)
    thread.start()
    print("ready", flush=True)
    for line in sys.stdin:
        command = line.strip()
        if command == "status":
            print(json.dumps(sum(board.connected() for board in boards)), flush=True)
        elif command == "go":
            running.set()
            print("going", flush=True)
        elif command == "stop":
            running.clear()
            finished.wait(10)
            counts = {
                board_name(first + i): {
                    "published": board.published,
                    "refused": board.refused,
                    "served": board.served,
                    **board.session_ends(),
                }
                for i, board in enumerate(boards)
            }
            print(json.dumps({"boards": counts, "late_ticks": late[0]}), flush=True)
        elif command == "quit":
            break
    for board in boards:
        board.close()
