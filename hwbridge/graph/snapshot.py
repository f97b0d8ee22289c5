"""What discovery reports: the entities alive on the graph at one moment (nodes, publishers,
subscribers, services, boards), plain data that the CLI, the ACL checks and the gateways read."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["GraphEntity", "GraphSnapshot"]


@dataclass(frozen=True, slots=True)
class GraphEntity:
    """Something alive on the graph, as discovery reports it."""

    kind: str  # node, pub, sub, srv, board
    node: str
    name: str = ""
    type: str = ""
    session: str = ""


@dataclass
class GraphSnapshot:
    """What discovery saw at one moment."""

    entities: list[GraphEntity] = field(default_factory=list)

    def of_kind(self, kind: str) -> list[GraphEntity]:
        return sorted((e for e in self.entities if e.kind == kind), key=lambda e: (e.name, e.node))

    @property
    def nodes(self) -> list[str]:
        return sorted({e.node for e in self.entities if e.kind == "node"})

    def topics(self) -> dict[str, set[str]]:
        """Topic name -> types published or subscribed under that name."""
        out: dict[str, set[str]] = {}
        for entity in self.entities:
            if entity.kind in ("pub", "sub"):
                out.setdefault(entity.name, set()).add(entity.type)
        return out

    def services(self) -> dict[str, set[str]]:
        out: dict[str, set[str]] = {}
        for entity in self.of_kind("srv"):
            out.setdefault(entity.name, set()).add(entity.type)
        return out
