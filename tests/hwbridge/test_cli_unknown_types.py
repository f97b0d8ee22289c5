"""Topics of a type the host has no definition of (a board's own package), through the CLI.

A real graph: a router in this process with raw publishers, as the bridge makes them for a
board's topics; the tools run as processes, as a user runs them.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from collections.abc import Iterator

import pytest
import yaml

from hwbridge import msg
from hwbridge.graph import ANY_TYPE, Graph, GraphConfig, RawMessage
from tests.netutil import wait_until

UNKNOWN = "foo_msgs/Bar"
UNKNOWN_MD5 = "0123456789abcdef0123456789abcdef"
PAYLOAD = bytes(range(7))
WRONG_MD5 = "f" * 32
"""Published as std_msgs/String but with another md5: another definition of that name."""


@pytest.fixture(scope="module")
def graph(endpoint: str, graph_domain: str) -> Iterator[Graph]:
    graph = Graph.embedded(listen=[endpoint], domain=graph_domain)
    node = graph.node("odd_board", namespace="/odd")
    bar = node.raw_publisher("bar", UNKNOWN, UNKNOWN_MD5)
    other = node.raw_publisher("other", "std_msgs/String", WRONG_MD5)
    stop = threading.Event()

    def run() -> None:
        while not stop.is_set():
            bar.publish_raw(PAYLOAD)
            other.publish_raw(b"\x02\x00\x00\x00hi")
            stop.wait(0.02)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    yield graph
    stop.set()
    thread.join()
    graph.close()


def cli(endpoint: str, domain: str, *argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hwbridge", "--endpoint", endpoint, "--domain", domain, *argv],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def test_a_raw_publisher_needs_no_definition(
    graph: Graph, endpoint: str, graph_domain: str
) -> None:
    """The graph itself: a raw subscriber gets the publisher's type name and md5 as given."""
    got: list[RawMessage] = []
    with Graph(GraphConfig.attached([endpoint], graph_domain)) as g:
        g.node("probe").subscriber("/odd/bar", ANY_TYPE, got.append, raw=True)
        assert wait_until(lambda: bool(got), 5.0)
    assert (got[0].type, got[0].md5, got[0].data) == (UNKNOWN, UNKNOWN_MD5, PAYLOAD)


def test_echo_shows_the_bytes_and_names_the_missing_definition_once(
    graph: Graph, endpoint: str, graph_domain: str
) -> None:
    done = cli(endpoint, graph_domain, "topic", "echo", "/odd/bar", "-n", "3")
    assert done.returncode == 0, done.stderr
    docs = [yaml.safe_load(d) for d in done.stdout.split("---\n") if d.strip()]
    assert docs == [{"type": UNKNOWN, "md5": UNKNOWN_MD5, "raw": PAYLOAD.hex()}] * 3
    note = f"no definition of {UNKNOWN} here: add its package with --msg-path; showing raw bytes"
    assert done.stderr.count(note) == 1, done.stderr

    done = cli(endpoint, graph_domain, "topic", "echo", "/odd/bar", "-n", "1", "--json")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == {"type": UNKNOWN, "md5": UNKNOWN_MD5, "raw": PAYLOAD.hex()}


def test_echo_refuses_a_known_name_with_another_md5(
    graph: Graph, endpoint: str, graph_domain: str
) -> None:
    """Decoding with another definition would print wrong values (issue 19 item 4)."""
    done = cli(endpoint, graph_domain, "topic", "echo", "/odd/other", "-n", "1", "--json")
    assert done.returncode == 1
    assert done.stdout == ""
    ours = msg.md5("std_msgs/String")
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith("error: /odd/other: the publisher sends std_msgs/String with md5 ")
    assert WRONG_MD5 in line and ours in line
    shown = cli(endpoint, graph_domain, "topic", "echo", "/odd/other", "-n", "1", "--hex")
    assert shown.returncode == 0, shown.stderr
    assert shown.stdout.startswith(b"\x02\x00\x00\x00hi".hex())


def test_list_info_and_hz_work_on_unknown_types(
    graph: Graph, endpoint: str, graph_domain: str
) -> None:
    done = cli(endpoint, graph_domain, "topic", "list", "-v")
    assert done.returncode == 0, done.stderr
    assert f"/odd/bar [{UNKNOWN}] 1 publisher(s)" in done.stdout
    done = cli(endpoint, graph_domain, "topic", "info", "/odd/bar")
    assert done.returncode == 0, done.stderr
    assert f"Type: {UNKNOWN}" in done.stdout
    done = cli(endpoint, graph_domain, "topic", "hz", "/odd/bar", "--duration", "1.2", "--json")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.splitlines()[-1])["rate_hz"] > 0
