"""Shared fixtures: a real Zenoh graph on a free loopback port (a router and its clients)."""

from __future__ import annotations

import signal
from collections.abc import Iterator

import pytest
from hypothesis import settings

from hwbridge.graph import Graph
from tests.netutil import free_port

pytest_plugins = ["tests.scheduling"]

# No per-example deadline anywhere: a busy machine stretches one example's wall time many times
# over (671 ms against the default 200 ms at load 30), which says nothing about the code. A test's
# own @settings keeps what it sets and takes the rest from this profile.
settings.register_profile("hwbridge", deadline=None)
settings.load_profile("hwbridge")

# The commands the tests start must meet SIGINT as they do when started from a terminal. A job
# started in the background of a script (``./tools/test &`` in a CI runner's shell, which has no
# job control) inherits SIGINT ignored, every process it starts keeps it ignored through exec,
# and Python then installs no KeyboardInterrupt handler: the tests that press Ctrl-C on a command
# (tests/hwbridge/test_sigint.py and others) failed by the dozen that way. A handler here is not
# inherited through exec: what the tests start begins with SIGINT's default action again.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="module")
def endpoint() -> str:
    """A loopback endpoint nothing listens on yet (one per test module)."""
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture(scope="module")
def graph_domain(request: pytest.FixtureRequest) -> str:
    """A graph domain of the module's own, so modules never see each other's topics."""
    return str(request.module.__name__).rsplit(".", 1)[-1]


@pytest.fixture(scope="module")
def router(endpoint: str, graph_domain: str) -> Iterator[Graph]:
    """The graph's owner (what a bridge runs), for the whole module."""
    graph = Graph.embedded(listen=[endpoint], domain=graph_domain)
    yield graph
    graph.close()


@pytest.fixture
def client(router: Graph, endpoint: str, graph_domain: str) -> Iterator[Graph]:
    """A graph client attached to the router (what CLI tools and nodes are)."""
    graph = Graph.attached(connect=[endpoint], domain=graph_domain)
    yield graph
    graph.close()
