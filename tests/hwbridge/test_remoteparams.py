"""Parameters read from another process's server (a shard of ``hwbridge up``): a bridge whose
boards read through :class:`RemoteParams` sees the values and changes of the server the graph's
owner hosts, over real Zenoh sessions (a router hosting the server, a client reading it)."""

from __future__ import annotations

import threading
from typing import Any

import pytest

from hwbridge.bridge import Bridge
from hwbridge.bridge.remoteparams import RemoteParams
from hwbridge.errors import HwBridgeError
from hwbridge.graph import Graph, ParamError, ParamServer
from tests.netutil import wait_until


def test_a_shards_bridge_reads_the_owners_parameters(router: Graph, client: Graph) -> None:
    server = ParamServer(router, {"/robot/wheel_radius": 0.033, "/robot/name": "r2"})
    bridge = Bridge(client, param_source=RemoteParams(client))
    assert bridge.get_param("/robot/wheel_radius") == 0.033
    assert bridge.get_param("/robot") == {"wheel_radius": 0.033, "name": "r2"}
    with pytest.raises(ParamError, match="no parameter /robot/missing"):
        bridge.get_param("/robot/missing")
    with pytest.raises(HwBridgeError, match="another process's server"):
        _ = bridge.params  # it hosts none: one server per graph, the owner's

    seen: list[tuple[str, Any]] = []
    lock = threading.Lock()

    def heard(name: str, value: Any) -> None:
        with lock:
            seen.append((name, value))

    remove = bridge.param_source.on_update(heard)
    later: list[str] = []
    bridge.param_source.on_update(lambda name, _value: later.append(name))

    def changed() -> bool:
        server.set("/robot/wheel_radius", 0.04)
        with lock:
            return ("/robot/wheel_radius", 0.04) in seen

    assert wait_until(changed, 20, step=0.2), seen  # the subscription reaches the router
    remove()
    server.set("/robot/late", 1)
    assert bridge.get_param("/robot/late") == 1
    assert wait_until(lambda: "/robot/late" in later, 20, step=0.1)  # the others hear it
    with lock:
        assert ("/robot/late", 1) not in seen  # a removed listener does not
    bridge.stop()
