"""A protocol and a link from another distribution, found only through their entry points.

``tests/plugins`` holds a distribution (``hwbridge_lineproto``, with its ``.dist-info``) that
registers the ``lines`` protocol and the ``linepipe://`` link; nothing in ``hwbridge/`` or
``protocols/`` names them. Putting it on ``sys.path`` is what installing it would do.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from hwbridge import msg
from hwbridge.bridge import BoardSpec, Bridge
from hwbridge.graph import Graph
from hwbridge.links import LinkClosedError, open_link
from hwbridge.protocols import registry
from tests.netutil import free_port, wait_until

PLUGINS = Path(__file__).resolve().parents[1] / "plugins"


@pytest.fixture
def plugin_path(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.syspath_prepend(str(PLUGINS))
    registry.refresh()
    yield
    monkeypatch.undo()
    registry.refresh()


class LineBoard:
    """The board: declares a publisher and a subscriber, publishes, records what it gets."""

    def __init__(self, url: str) -> None:
        self.link = open_link(url)
        self.received: list[bytes] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def table(self) -> bytes:
        string, boolean = msg.md5("std_msgs/String"), msg.md5("std_msgs/Bool")
        return (
            f"TOPIC 1 pub chatter std_msgs/String {string}\n"
            f"TOPIC 2 sub led std_msgs/Bool {boolean}\nREADY\n"
        ).encode()

    def _run(self) -> None:
        with contextlib.suppress(LinkClosedError):  # the bridge's end closes first at the end
            self._serve()

    def _serve(self) -> None:
        self.link.write(self.table())  # this board speaks first, as it boots
        buffered = b""
        count = 0
        while not self._stop.is_set():
            buffered += self.link.read(4096, timeout=0.05)
            *lines, buffered = buffered.split(b"\n")
            for line in lines:
                if line == b"HELLO":
                    self.link.write(self.table())
                elif line.startswith(b"MSG 2 "):
                    self.received.append(bytes.fromhex(line[6:].decode()))
            count += 1
            text = msg.encode(msg.from_dict("std_msgs/String", {"data": f"hi {count}"}))
            self.link.write(f"MSG 1 {text.hex()}\n".encode())

    def start(self) -> LineBoard:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.link.close()


def test_a_plugin_protocol_and_link_bridge_a_board(plugin_path: None) -> None:
    assert "lines" in registry.protocol_names()
    graph = Graph.embedded(listen=[f"tcp/127.0.0.1:{free_port()}"], domain="plugins")
    bridge = Bridge(graph)
    board: LineBoard | None = None
    try:
        connection = bridge.add_board(BoardSpec("linepipe://robot?end=0", namespace="/lb"))
        board = LineBoard("linepipe://robot?end=1").start()
        heard: list[str] = []
        node = graph.node("listener")
        node.subscriber("/lb/chatter", "std_msgs/String", lambda m: heard.append(m.data))
        assert wait_until(lambda: len(heard) >= 3), connection.info()
        assert heard[-1].startswith("hi ")
        info = connection.info()
        assert info["protocol"] == "lines"  # detected by the plugin's detector
        assert info["state"] == "connected"
        assert info["stats"]["frames_received"] > 0

        led = node.publisher("/lb/led", "std_msgs/Bool")
        assert wait_until(lambda: led.publish({"data": True}) or bool(board and board.received))
        assert board.received[0] == b"\x01"
    finally:
        bridge.stop()
        graph.close()
        if board is not None:
            board.stop()


def test_an_unknown_protocol_names_the_registered_ones(plugin_path: None) -> None:
    with pytest.raises(registry.UnknownProtocolError, match="auto, native, rosserial, lines"):
        BoardSpec("linepipe://x", protocol="morse")
