"""Pausing a running bridge's board from another process (``hwbridge firmware upload``).

Every board of a running bridge (``hwbridge connect``, ``hwbridge up``) serves a control
queryable next to its info one (:func:`control_key`). A query with the
JSON payload ``{"pause": SECONDS, "reason": TEXT}`` makes the board end its session (its
endpoints leave the graph, a goodbye is written), close its link and hold off reopening it until
``{"resume": true}`` comes, or the SECONDS run out (logged); a later pause extends the hold.
The reply comes once the link is closed.

:class:`BridgePause` is the client: it finds the board whose link is a given device and whose
bridge is a given process (the holder of the port's lock), pauses it, keeps the pause alive
while the upload runs (a short pause renewed, so a killed uploader leaves the board paused for
:data:`LEASE` seconds at most) and resumes it.
"""

from __future__ import annotations

import json
import logging
import os
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final

from hwbridge.errors import HwBridgeError
from hwbridge.graph.names import encode_segment

if TYPE_CHECKING:
    from hwbridge.graph import Graph

__all__ = ["LEASE", "BridgePause", "HeldBoard", "control_key", "find_holding_board"]

log = logging.getLogger("hwbridge.bridge.control")

LEASE: Final = 60.0
"""Seconds each pause request holds the board off; renewed every third of it."""


def control_key(prefix: str, name: str) -> str:
    """Zenoh key of a board's control queryable (pause and resume), beside its info one
    (``PREFIX/board/NAME``); this module is what the board's connection and its clients share,
    so it never imports the connection."""
    return f"{prefix}/board/{encode_segment(name)}/control"


@dataclass(frozen=True)
class HeldBoard:
    """A bridge's board whose link is the port: its name, URL and the bridge's process."""

    name: str
    url: str
    pid: int


def _replies(graph: Graph, key: str, payload: dict[str, Any] | None, timeout: float) -> list[Any]:
    import zenoh

    replies = graph.session.get(
        key,
        payload=json.dumps(payload).encode() if payload is not None else None,
        timeout=timeout,
        consolidation=zenoh.ConsolidationMode.NONE,
    )
    answers: list[Any] = []
    for reply in replies:
        if reply.ok is not None:
            answers.append(json.loads(bytes(reply.ok.payload.to_bytes())))
        elif reply.err is not None:
            raise HwBridgeError(reply.err.payload.to_string())
    return answers


def find_holding_board(
    graph: Graph, device: str, pid: int | None, timeout: float = 2.0
) -> HeldBoard | None:
    """The board on the graph whose link is ``device`` (symlinks resolved) in the bridge
    process ``pid`` (any process when None); None when no bridge on the graph has it."""
    wanted = os.path.realpath(device)
    for info in _replies(graph, f"{graph.prefix}/board/*", None, timeout):
        if not isinstance(info, dict) or info.get("device") != wanted:
            continue
        if pid is not None and info.get("pid") != pid:
            continue
        return HeldBoard(str(info["name"]), str(info.get("url", "")), int(info.get("pid", 0)))
    return None


class BridgePause:
    """Pauses one board of a running bridge (``with``: paused inside, resumed after, however
    the block ends). The lease is renewed on a thread until :meth:`resume`."""

    def __init__(self, graph: Graph, board: HeldBoard, reason: str = "an upload") -> None:
        self.graph = graph
        self.board = board
        self.reason = reason
        self._done = threading.Event()
        self._renewer: threading.Thread | None = None

    def request(self, request: dict[str, Any], timeout: float = 20.0) -> dict[str, Any]:
        """Send one control request to the board; its reply (HwBridgeError: an error reply, or
        none within ``timeout`` seconds)."""
        key = control_key(self.graph.prefix, self.board.name)
        try:
            answers = _replies(self.graph, key, request, timeout)
        except HwBridgeError as exc:
            raise HwBridgeError(f"board {self.board.name}: {exc}") from exc
        if not answers:
            raise HwBridgeError(
                f"board {self.board.name} of the bridge (pid {self.board.pid}) did not answer "
                "the control request"
            )
        answer: dict[str, Any] = answers[0]
        return answer

    def pause(self) -> None:
        """Ask the board to release its port; returns once it has (HwBridgeError if not)."""
        answer = self.request({"pause": LEASE, "reason": self.reason})
        if not answer.get("released"):
            raise HwBridgeError(
                f"board {self.board.name} (pid {self.board.pid}) did not release its port"
            )
        self._renewer = threading.Thread(target=self._renew, name="pause-renew", daemon=True)
        self._renewer.start()

    def _renew(self) -> None:
        while not self._done.wait(LEASE / 3):
            try:
                self.request({"pause": LEASE, "reason": self.reason})
            except HwBridgeError as exc:
                log.warning("renewing the pause failed: %s", exc)

    def resume(self) -> None:
        """Tell the board to reopen its port (the renewing stops first)."""
        self._done.set()
        if self._renewer is not None:
            self._renewer.join(25.0)
        self.request({"resume": True})

    def __enter__(self) -> BridgePause:
        self.pause()
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            self.resume()
        except HwBridgeError as exc_:
            log.error("could not resume board %s: %s", self.board.name, exc_)
