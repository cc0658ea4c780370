"""Live view: the Foxglove WebSocket bridge (pure core and node)."""
