"""The bridge: boards on links, mirrored onto the graph.

::

    from hwbridge.bridge import Bridge, BoardSpec

    with Bridge() as bridge:                          # embedded graph on tcp/127.0.0.1:7447
        bridge.add_board(BoardSpec("/dev/ttyACM0", baud=57600, namespace="/diffbot"))
        bridge.wait()                                 # until stop() or Ctrl-C

Each board runs in its own thread (:class:`~hwbridge.bridge.board.BoardConnection`) and comes
back by itself after a reset, an unplugged cable or a port that disappears. Whatever protocol a
board speaks (:mod:`hwbridge.protocols.registry`), one
:class:`~hwbridge.bridge.adapter.SessionAdapter` mirrors its session onto the graph. The bridge
also hosts the graph's parameter server, which boards read from.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from hwbridge import msg
from hwbridge.bridge.board import BoardConnection, BoardSpec
from hwbridge.errors import HwBridgeError
from hwbridge.graph import Graph, GraphConfig, ParamServer

__all__ = ["Bridge"]

log = logging.getLogger("hwbridge.bridge")


class Bridge:
    """Owns a graph session, a parameter server and one connection per board."""

    def __init__(
        self,
        graph: Graph | None = None,
        *,
        config: GraphConfig | None = None,
        params: dict[str, Any] | None = None,
        registry: msg.TypeRegistry | None = None,
    ) -> None:
        self._own_graph = graph is None
        self.graph = graph if graph is not None else Graph(config or GraphConfig.embedded())
        self.registry = registry or self.graph.registry
        self.params = ParamServer(self.graph, params)
        self.boards: dict[str, BoardConnection] = {}
        self._stopped = threading.Event()

    def __enter__(self) -> Bridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def add_board(self, spec: BoardSpec) -> BoardConnection:
        """Start keeping a board connected."""
        if spec.name in self.boards:
            raise HwBridgeError(
                f"two boards named {spec.name!r}: give one a name (--name) or a namespace"
            )
        board = BoardConnection(self, spec)
        self.boards[spec.name] = board
        board.start()
        log.info("board %s on %s (%s)", spec.name, spec.url, spec.protocol)
        return board

    def get_param(self, name: str) -> Any:
        """A parameter for a board (ParamError if missing)."""
        return self.params.get(name)

    def wait(self, timeout: float | None = None) -> bool:
        """Block until :meth:`stop` (True) or ``timeout`` (False)."""
        return self._stopped.wait(timeout)

    def stop(self) -> None:
        """Stop every board (TX_STOP / goodbye where the link lives) and close the graph."""
        if self._stopped.is_set():
            return
        self._stopped.set()
        for board in self.boards.values():
            board.stop()
        if self._own_graph:
            self.graph.close()
