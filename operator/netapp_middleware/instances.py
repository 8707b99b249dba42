"""The NetApp instances and the robots' deployments on them, as the registry sees them (no I/O).

An instance's `claims` are the ids of the deployments on it, and of the warm holds (`WARM_PREFIX`: a standby or a
robot's route keeping it warm for robots that may come), which are no robot's.
"""

from __future__ import annotations

import asyncio
import hashlib
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from netapp.protocol import TOKEN_DIGEST_ENV

from .backends.base import DEPLOYING, FAILED, PENDING, READY, Claim, InstanceState
from .channel import with_netapp
from .priorities import with_env

if TYPE_CHECKING:
    from .tracing import DeploymentTrace

WARM_PREFIX = "warm:"  # the claim id of a warm hold: warm:<app>:<placement>


def warm_claim(app: str, placement: str) -> str:
    return f"{WARM_PREFIX}{app}:{placement}"


def is_warm(claim: str) -> bool:
    return claim.startswith(WARM_PREFIX)


def hold_record(claim: str, placement: str | None) -> Claim:
    """A warm hold as the backend records it beside the robots' claims (no robot's: an empty robot id), so that a
    restarted middleware takes the hold back instead of warming a netapp again."""
    return Claim(deployment_id=claim, robot_id="", placement=placement, reuse=True, created_at=0.0)


def robot_claims(claims: set[str]) -> int:
    """How many of an instance's claims are robots' deployments (not warm holds)."""
    return sum(1 for c in claims if not is_warm(c))


@dataclass(eq=False)
class Instance:
    """One NetApp, as the registry sees it."""

    name: str
    app: str
    placement: str | None
    shared: bool
    state: InstanceState = field(default_factory=lambda: InstanceState(PENDING, message="waiting for the backend"))
    version: int = 0
    last_ready_url: str | None = None
    claims: set[str] = field(default_factory=set)
    token: str | None = None  # the bearer token its netapp needs (None: it needs none)
    class_tokens: dict[str, str] = field(default_factory=dict)  # the tokens that grant a class (priorities.py)
    changed: asyncio.Event = field(default_factory=asyncio.Event)
    # Serialises this instance's backend calls (create, record, delete), so a later record never lands first.
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    trace: DeploymentTrace | None = None  # the trace of the deployment that created it (docs/tracing.md)
    # The model its netapp serves, as the catalogue named it (`rollouts.ModelKey`): the one it was started with, or
    # the last promoted; the catalogue naming another starts a rollout on it (model_rollouts.py). None: unknown (taken
    # back at a restart).
    model_key: tuple[str, str] | None = None
    # When its create began and returned, and when it was first Ready (monotonic ns; 0: not yet): its trace's spans.
    create_started_ns: int = 0
    create_done_ns: int = 0
    ready_ns: int = 0

    @property
    def stamps(self) -> tuple[int, int, int]:
        return self.create_started_ns, self.create_done_ns, self.ready_ns

    def notify(self) -> None:
        self.changed.set()
        self.changed = asyncio.Event()


@dataclass(eq=False)
class Deployment:
    """One robot's claim on one instance, or on several for a hedged deployment (primary first)."""

    id: str
    robot_id: str
    app: str
    placement: str | None
    reuse: bool
    instances: list[Instance]
    created_at: float
    meta: dict[str, Any] = field(default_factory=dict)
    deleted: bool = False
    # Added to the instances' versions so that `version` only grows when a switchover swaps the instance.
    version_base: int = 0
    arrived_at: float = field(default_factory=time.time)  # on its current placement since
    history: list[dict[str, Any]] = field(default_factory=list)  # switchovers, oldest first (bounded)
    note: str = ""  # the last switchover decision worth telling the robot
    moving: bool = False
    trace: DeploymentTrace | None = None  # sampled: ended when its URL is first handed out (`tracing`)

    @property
    def instance(self) -> Instance:
        """The primary instance (the only one unless hedged)."""
        return self.instances[0]

    @property
    def hedge(self) -> list[str | None] | None:
        return self.meta.get("hedge")

    @property
    def version(self) -> int:
        return self.version_base + sum(i.version for i in self.instances)

    def claim(self) -> Claim:
        return Claim(
            deployment_id=self.id,
            robot_id=self.robot_id,
            placement=self.placement,
            reuse=self.reuse,
            created_at=self.created_at,
            meta=self.meta,
        )

    def view(self) -> dict[str, Any]:
        phase, message = combined_state([i.state for i in self.instances])
        if self.note:
            message = f"{message}; {self.note}" if message else self.note
        state = self.instance.state
        shown = self.instance if state.phase == READY else next(iter(self.ready()), self.instance)
        view = {
            "id": self.id,
            "app": self.app,
            "placement": self.placement,
            "reuse": self.reuse,
            "status": phase,
            "url": self.address(shown),
            "urls": [self.address(i) for i in self.ready()],
            "pool": state.pool,
            "message": message,
            "netapp": self.instance.name,
            "robots": robot_claims(self.instance.claims),
            "version": self.version,
            "createdAt": self.created_at,
            "history": list(self.history),
            **({"token": token} if (token := self.token_on(self.instance)) else {}),
        }
        if self.hedge:
            view["hedge"] = [
                {
                    "placement": i.placement,
                    "status": i.state.phase,
                    "url": self.address(i),
                    "pool": i.state.pool,
                    **({"token": token} if (token := self.token_on(i)) else {}),
                }
                for i in self.instances
            ]
        return view

    def address(self, instance: Instance) -> str | None:
        """Where this robot sends its frames to reach `instance` (None until it has a URL): the NetApp's URL, or
        for an app whose channel is a broker, the broker's URL naming the NetApp (netapp_middleware.channel)."""
        channel = self.meta.get("channel")
        if instance.state.url is None or not channel:
            return instance.state.url
        return with_netapp(channel, instance.name)

    def token_on(self, instance: Instance) -> str | None:
        """The token this robot presents to `instance`: its class's (`meta["priority"]`), else the NetApp's."""
        return instance.class_tokens.get(self.meta.get("priority", ""), instance.token)

    def ready(self) -> list[Instance]:
        return [i for i in self.instances if i.state.phase == READY and i.state.url]


def combined_state(states: list[InstanceState]) -> tuple[str, str]:
    """A deployment's phase and message from its instances': Ready once every one is Ready or Failed and one is
    Ready (a hedge that lost one netapp still serves), Failed when all failed, else the least advanced phase."""
    if len(states) == 1:
        return states[0].phase, states[0].message
    phases = [s.phase for s in states]
    failed = [s.message for s in states if s.phase == FAILED]
    if all(p in (READY, FAILED) for p in phases) and READY in phases:
        return READY, "; ".join(["ready", *(f"one failed: {m}" for m in failed)])
    if all(p == FAILED for p in phases):
        return FAILED, "; ".join(failed)
    waiting = [s for s in states if s.phase not in (READY, FAILED)]
    slowest = min(waiting, key=lambda s: (PENDING, DEPLOYING).index(s.phase) if s.phase in (PENDING, DEPLOYING) else 2)
    return slowest.phase, slowest.message


def with_token_digest(spec: dict[str, Any], token: str) -> dict[str, Any]:
    """The spec with the netapp told to need `token`: its SHA-256 in the environment (`netapp serve` reads
    NETAPP_TOKEN_SHA256). Only the digest goes into the NetApp, so reading NetApps gives nobody the token."""
    return with_env(spec, TOKEN_DIGEST_ENV, hashlib.sha256(token.encode()).hexdigest())
