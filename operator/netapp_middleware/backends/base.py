"""The contract between the deployment registry and a backend."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

PENDING, DEPLOYING, READY, FAILED = "Pending", "Deploying", "Ready", "Failed"
IDLE = "Idle"  # scaled to zero after spec.scaling.idleToZero without a robot; `wake` brings it back, same URL


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


class RolloutRefused(ValueError):
    """A netapp answered a rollout's request with a refusal (a value out of range, one under way): said once, tried
    again when the request changes. A plain ValueError from `rollout` is a netapp not there to ask (stopping,
    asleep, not answering): tried again on the next tick, nothing said."""


class RolloutSink(Protocol):
    """Who keeps the record of the rollouts on a backend's NetApps (netapp_middleware.model_rollouts): a backend
    with a `rollout_sink` attribute is given one, and tells it what only the backend sees."""

    def under_way(self, name: str) -> bool:
        """Whether NetApp `name` runs a rollout without a verdict yet."""

    def observe(self, name: str, app: str, state: dict[str, Any]) -> None:
        """NetApp `name`'s rollout as someone else drives it (GET /rollout's terms)."""

    def ended(self, name: str, state: dict[str, Any] | None = None) -> None:
        """NetApp `name`'s netapp stopped (or the NetApp is gone); `state`: its rollout as last read, if just read."""


class Backend(Protocol):
    """Creates, follows and deletes NetApps by name; reports every state change through `report`.

    Optional: `wake(name)`, bring a NetApp asleep at zero (IDLE) back, or restart its quiet clock (a robot was
    just handed its URL); `refuse(spec) -> str | None`, why it cannot run a spec as it says (one line naming the
    field), asked before anything is claimed; `rollout` and `rollout_state` (netapp_middleware.model_rollouts);
    `rollout_sink`, a `RolloutSink` told when a rollout's netapp stops."""

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
