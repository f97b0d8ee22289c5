"""The host graph on Eclipse Zenoh (see :mod:`hwbridge.graph.core`)."""

from hwbridge.graph.config import DEFAULT_ENDPOINT, GraphConfig
from hwbridge.graph.core import (
    ANY_TYPE,
    DeferredReply,
    Graph,
    GraphEntity,
    GraphSnapshot,
    Node,
    Publisher,
    RawMessage,
    ServiceError,
    ServiceServer,
    Subscriber,
)
from hwbridge.graph.names import GraphNameError, resolve_name
from hwbridge.graph.params import ParamClient, ParamError, ParamHost, ParamServer

__all__ = [
    "ANY_TYPE",
    "DEFAULT_ENDPOINT",
    "DeferredReply",
    "Graph",
    "GraphConfig",
    "GraphEntity",
    "GraphNameError",
    "GraphSnapshot",
    "Node",
    "ParamClient",
    "ParamError",
    "ParamHost",
    "ParamServer",
    "Publisher",
    "RawMessage",
    "ServiceError",
    "ServiceServer",
    "Subscriber",
    "resolve_name",
]
