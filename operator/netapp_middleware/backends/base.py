"""The contract between the deployment registry and a backend."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Protocol

PENDING, DEPLOYING, READY, FAILED = "Pending", "Deploying", "Ready", "Failed"


@dataclass(frozen=True)
class InstanceState:
    """What a backend knows about one NetApp: the NetApp status' phase, url, pool and a human message."""

    phase: str
    url: str | None = None
    pool: str | None = None
    message: str = ""


# Called by a backend on the event loop whenever an instance's state changes.
StateCallback = Callable[[str, InstanceState], None]


class Backend(Protocol):
    """Creates, follows and deletes NetApps by name; reports every state change through `report`."""

    name: str

    async def start(self, report: StateCallback) -> None:
        """Begin following state; called once before any create."""

    async def create(self, name: str, app: str, spec: dict[str, Any], labels: dict[str, str]) -> None:
        """Start a NetApp; raise on an immediate failure (the registry marks the instance Failed)."""

    async def delete(self, name: str) -> None:
        """Stop a NetApp and free what it holds; deleting an unknown name is not an error."""

    async def close(self) -> None:
        """Stop following; a backend whose NetApps cannot outlive the middleware stops them here."""
