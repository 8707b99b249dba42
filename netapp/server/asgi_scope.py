"""Reading an ASGI connection scope (the replica's router and the frames endpoint both do)."""

from __future__ import annotations

from typing import Any


def header(scope: dict[str, Any], name: bytes) -> str | None:
    """The value of header `name` (lower-case bytes), None when the request has none."""
    for key, value in scope["headers"]:
        if key.lower() == name:
            return value.decode("latin-1")
    return None
