"""Shared fixtures: a real Zenoh graph on a free loopback port (a router and its clients)."""

from __future__ import annotations

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
