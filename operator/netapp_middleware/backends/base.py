"""The contract between the deployment registry and a backend."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

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


@dataclass(frozen=True)
class Claim:
    """One robot's deployment on an instance, as recorded with the instance so that it survives a restart."""

    deployment_id: str
    robot_id: str
    placement: str | None
    reuse: bool
    created_at: float
    meta: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Recovered:
    """An instance found at start: what a previous middleware process created and who was using it."""

    name: str
    app: str
    placement: str | None
    shared: bool
    state: InstanceState
    claims: tuple[Claim, ...]


class Backend(Protocol):
    """Creates, follows and deletes NetApps by name; reports every state change through `report`.

    Optional: `refuse(spec) -> str | None`, why it cannot run a spec as it says (one line naming the field), asked
    before anything is claimed; `rollout` and `rollout_state` (netapp_middleware.model_rollouts)."""

    name: str

    async def start(self, report: StateCallback) -> list[Recovered]:
        """Begin following state; called once before any create. Returns the instances that outlived a previous
        middleware process (none for a backend whose instances die with it)."""

    async def create(
        self,
        name: str,
        app: str,
        placement: str | None,
        spec: dict[str, Any],
        labels: dict[str, str],
        annotations: dict[str, str] | None = None,
    ) -> None:
        """Start a NetApp; raise on an immediate failure (the registry marks the instance Failed). `annotations`:
        what to note on it beside the labels (the deployment's traceparent), where the backend can."""

    async def record(self, name: str, claims: list[Claim]) -> None:
        """Store who uses the instance with it (called after create and whenever its claims change)."""

    async def delete(self, name: str) -> None:
        """Stop a NetApp and free what it holds; deleting an unknown name is not an error."""

    async def announce(self, name: str, type_: str, reason: str, message: str) -> None:
        """Tell whoever watches the NetApp of a decision about it (Normal or Warning, a CamelCase reason); never
        raises: an announcement is advice."""

    async def close(self) -> None:
        """Stop following; a backend whose NetApps cannot outlive the middleware stops them here."""
