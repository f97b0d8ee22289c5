"""The port between a board's connection and its session's adapter (:mod:`hwbridge.bridge.port`).

No graph and no link: the port gets a stand-in for the bridge's parameter server (which, as the
real one, calls a snapshot of its listeners outside its lock) and a session that records what
the adapter asks of it. The end-to-end counterparts are in ``test_resets.py``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any, TypeVar, cast

import pytest

from hwbridge.bridge.adapter import SessionAdapter
from hwbridge.bridge.port import BoardPort, ParamListener
from hwbridge.errors import LinkError
from hwbridge.graph import Node, ParamError
from hwbridge.protocols import base
from hwbridge.protocols.registry import get_protocol

T = TypeVar("T")


class Params:
    """The parameter server's listener API: ``on_update`` and its remover."""

    def __init__(self, values: dict[str, Any] | None = None) -> None:
        self.values = dict(values or {})
        self.listeners: list[ParamListener] = []

    def get(self, name: str) -> Any:
        if name not in self.values:
            raise ParamError(f"no parameter {name}")
        return self.values[name]

    def on_update(self, listener: ParamListener) -> Callable[[], None]:
        self.listeners.append(listener)

        def remove() -> None:
            if listener in self.listeners:
                self.listeners.remove(listener)

        return remove

    def snapshot(self) -> list[ParamListener]:
        """The listeners a change announced now would call (taken before they are called)."""
        return list(self.listeners)

    def set(self, name: str, value: Any) -> None:
        self.values[name] = value
        for listener in self.snapshot():
            listener(name, value)


class Session:
    """What the adapter calls on a session in these tests, recorded."""

    def __init__(self) -> None:
        self.answered: list[tuple[int, Any]] = []
        self.pushed: list[tuple[str, Any]] = []

    def answer_param(self, request_id: int, value: Any) -> None:
        self.answered.append((request_id, value))

    def push_param(self, name: str, value: Any) -> None:
        self.pushed.append((name, value))


def port_for(params: Params, session: Session) -> BoardPort:
    def call(action: Callable[[base.BoardSession], T], /) -> T:
        return action(cast(base.BoardSession, session))

    return BoardPort(
        name="uno",
        log=logging.getLogger("hwbridge.board.uno"),
        node=cast(Node, object()),  # nothing is declared in these tests
        service_timeout=5.0,
        call=call,
        resolve=lambda name: name if name.startswith("/") else f"/uno/{name}",
        set_state=lambda state, **detail: None,
        get_param=params.get,
        on_param_update=params.on_update,
    )


def test_closing_the_port_removes_every_listener_of_the_session() -> None:
    params, heard = Params(), []
    port = port_for(params, Session())
    port.listen_params(lambda name, value: heard.append(("a", name, value)))
    port.listen_params(lambda name, value: heard.append(("b", name, value)))
    assert port.listeners == 2
    assert len(params.listeners) == 2
    params.set("/speed", 1)
    port.close()
    port.close()  # idempotent
    assert port.closed
    assert port.listeners == 0
    assert params.listeners == []
    params.set("/speed", 2)
    assert heard == [("a", "/speed", 1), ("b", "/speed", 1)]


def test_a_closed_port_calls_no_listener_not_even_one_announced_before_it_closed() -> None:
    """The parameter server calls a snapshot of its listeners outside its lock: a change
    announced as the session ended reaches the port after its close, and goes no further."""
    params, heard = Params(), []
    port = port_for(params, Session())
    port.listen_params(lambda name, value: heard.append(name))
    late = params.snapshot()
    port.close()
    for listener in late:
        listener("/speed", 3)
    assert heard == []


def test_a_closed_port_registers_no_listener() -> None:
    params = Params()
    port = port_for(params, Session())
    port.close()
    port.listen_params(lambda name, value: None)
    assert port.listeners == 0
    assert params.listeners == []


@pytest.mark.parametrize("protocol", ["native", "rosserial"])
def test_an_adapter_listens_while_its_session_lives_and_not_after(protocol: str) -> None:
    """One listener per adapter, through its port; the board's parameter reaches the session
    while the adapter lives, and the listener is gone once the adapter closed."""
    params, session = Params({"/uno/gain": 2}), Session()
    port = port_for(params, session)
    adapter = SessionAdapter(port, get_protocol(protocol), cast(base.BoardSession, session))
    assert port.listeners == 1
    assert len(params.listeners) == 1
    adapter.on_event(base.ParamRequest(request_id=7, name="gain", subscribe=True))
    assert session.answered == [(7, 2)]
    params.set("/uno/gain", 3)
    params.set("/other", 1)  # not the board's: not pushed
    assert session.pushed == [("gain", 3)]
    assert adapter.close(LinkError("cable pulled")) == []
    assert port.closed
    assert params.listeners == []
    params.set("/uno/gain", 4)
    assert session.pushed == [("gain", 3)]
