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
also hosts the graph's parameter server, which boards read from (unless ``param_source`` says
where else they read: a shard of ``hwbridge up`` reads the parent's, see
:mod:`hwbridge.bridge.remoteparams`).
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING, Any

from hwbridge import msg
from hwbridge.bridge.board import BoardConnection, BoardSpec
from hwbridge.errors import HwBridgeError
from hwbridge.graph import Graph, GraphConfig, ParamServer

if TYPE_CHECKING:
    from hwbridge.bridge.remoteparams import ParamSource

__all__ = ["Bridge"]

log = logging.getLogger("hwbridge.bridge")


class Bridge:
    """Owns a graph session, a parameter server (unless ``param_source`` is given: the boards
    read parameters from there, and this bridge hosts none) and one connection per board."""

    def __init__(
        self,
        graph: Graph | None = None,
        *,
        config: GraphConfig | None = None,
        params: dict[str, Any] | None = None,
        registry: msg.TypeRegistry | None = None,
        param_source: ParamSource | None = None,
    ) -> None:
        self._own_graph = graph is None
        self.graph = graph if graph is not None else Graph(config or GraphConfig.embedded())
        self.registry = registry or self.graph.registry
        self._server: ParamServer | None = None
        if param_source is None:
            self._server = param_source = ParamServer(self.graph, params)
        self.param_source: ParamSource = param_source
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

    @property
    def params(self) -> ParamServer:
        """The parameter server this bridge hosts (HwBridgeError: it hosts none)."""
        if self._server is None:
            raise HwBridgeError("this bridge reads its parameters from another process's server")
        return self._server

    def get_param(self, name: str) -> Any:
        """A parameter for a board (ParamError if missing)."""
        return self.param_source.get(name)

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
