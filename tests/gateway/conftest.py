"""What the gateway tests share: a graph client attached to the module's running robot."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from hwbridge.graph import Graph
from tests.gateway.harness import Robot


@pytest.fixture(scope="module")
def graph(robot: Robot) -> Iterator[Graph]:
    """Attached to ``robot`` (each test module's own fixture) for the whole module."""
    with Graph.attached(connect=[robot.endpoint], domain="gw") as attached:
        yield attached
