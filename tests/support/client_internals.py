"""What a test may read of a NetAppClient's insides, in one place, so a change of those insides changes one line."""

from __future__ import annotations


def socketio_way(client) -> str:
    """How a NetAppClient's Socket.IO session reaches its (first) netapp now: "websocket" or "polling"."""
    return client._links[0].carrier._sio.eio.current_transport  # the transport's own python-socketio client
