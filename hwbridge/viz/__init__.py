"""Live views of the graph: the Foxglove WebSocket bridge (``hwbridge viz``) and plots."""
