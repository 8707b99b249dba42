"""Robots' deployments and the NetApp instances behind them.

A deployment is one robot's claim on an instance; with reuse, robots asking for the same app and placement claim
the same instance (1:n) and the instance is deleted when its last claim goes. Everything here runs on the event
loop, so no locks: a backend reports state changes through `report`, and waiters are woken by an asyncio.Event.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import secrets
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from netapp_operator.constants import LABEL_APP, LABEL_SHARED

from netapp.protocol import TOKEN_DIGEST_ENV

from .backends.base import DEPLOYING, FAILED, PENDING, READY, Backend, Claim, InstanceState
from .catalogue import App, render_spec

log = logging.getLogger(__name__)


class NotFound(Exception):
    """No such deployment for this robot (another robot's deployment is reported the same way)."""


class QuotaExceeded(Exception):
    """The robot already has as many deployments as it may."""


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
    changed: asyncio.Event = field(default_factory=asyncio.Event)
    # Serialises this instance's backend calls (create, record, delete), so a later record never lands first.
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)

    def notify(self) -> None:
        self.changed.set()
        self.changed = asyncio.Event()


@dataclass(eq=False)
class Deployment:
    id: str
    robot_id: str
    app: str
    placement: str | None
    reuse: bool
    instance: Instance
    created_at: float
    meta: dict[str, Any] = field(default_factory=dict)
    deleted: bool = False

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
        state = self.instance.state
        return {
            "id": self.id,
            "app": self.app,
            "placement": self.placement,
            "reuse": self.reuse,
            "status": state.phase,
            "url": state.url,
            "pool": state.pool,
            "message": state.message,
            "netapp": self.instance.name,
            "robots": len(self.instance.claims),
            "version": self.instance.version,
            "createdAt": self.created_at,
            **({"token": self.instance.token} if self.instance.token else {}),
        }


def with_token_digest(spec: dict[str, Any], token: str) -> dict[str, Any]:
    """The spec with the netapp told to need `token`: its SHA-256 in the environment (`netapp serve` reads
    NETAPP_TOKEN_SHA256). Only the digest goes into the NetApp, so reading NetApps gives nobody the token."""
    env = [e for e in spec.get("env", []) if e.get("name") != TOKEN_DIGEST_ENV]
    digest = hashlib.sha256(token.encode()).hexdigest()
    return {**spec, "env": [*env, {"name": TOKEN_DIGEST_ENV, "value": digest}]}


def instance_name(app: str) -> str:
    """A DNS-1123 NetApp name: the app's name (trimmed) and a random suffix."""
    stem = "".join(c if c.isalnum() else "-" for c in app.lower()).strip("-")[:50] or "netapp"
    return f"{stem}-{secrets.token_hex(4)}"


class Registry:
    """Creates, shares, follows and deletes deployments on one backend."""

    def __init__(
        self,
        backend: Backend,
        max_per_robot: int = 16,
        max_netapps: int = 64,
        token_for: Callable[[str], str] | None = None,
    ) -> None:
        self.backend = backend
        # A NetApp's token from its name: derived from the middleware's stable key (TokenSigner.netapp_token), so a
        # restarted middleware hands out the same token; without one, random (kept in memory).
        self.token_for = token_for or (lambda name: secrets.token_urlsafe(32))
        # Robots create cluster workloads through us: a runaway robot, or many robots, must not fill the cluster.
        self.max_per_robot = max_per_robot
        self.max_netapps = max_netapps
        self._deployments: dict[str, Deployment] = {}
        self._instances: dict[str, Instance] = {}
        self._shared: dict[tuple[str, str | None], Instance] = {}
        self._tasks: set[asyncio.Task[None]] = set()

    async def start(self) -> None:
        """Start the backend and take back the instances (and robots' deployments) that outlived a restart."""
        for found in await self.backend.start(self.report):
            instance = Instance(
                name=found.name,
                app=found.app,
                placement=found.placement,
                shared=found.shared,
                state=found.state,
                token=self.token_for(found.name),  # what it was given, if it needs one (a netapp without ignores it)
            )
            if found.state.phase == READY:
                instance.last_ready_url = found.state.url
            self._instances[instance.name] = instance
            if not found.claims:  # its last robot left, or its creator died, before the backend heard of it
                log.info("NetApp %s has no robots: deleting it", found.name)
                self._forget(instance)
                self._spawn(self._delete_instance(instance))
                continue
            if found.shared:
                self._shared.setdefault((found.app, found.placement), instance)
            for claim in found.claims:
                self._deployments[claim.deployment_id] = Deployment(
                    id=claim.deployment_id,
                    robot_id=claim.robot_id,
                    app=found.app,
                    placement=claim.placement,
                    reuse=claim.reuse,
                    instance=instance,
                    created_at=claim.created_at,
                    meta=dict(claim.meta),
                )
                instance.claims.add(claim.deployment_id)
            log.info(
                "took back NetApp %s (%s) with %d robot deployment(s)", found.name, found.state.phase, len(found.claims)
            )

    async def close(self, grace_s: float = 5.0) -> None:
        """Let pending creates, records and deletes finish (briefly: a restart relies on what they record)."""
        if self._tasks:
            _, pending = await asyncio.wait(list(self._tasks), timeout=grace_s)
            for task in pending:
                task.cancel()
        await self.backend.close()

    # -- robot-facing operations ---------------------------------------------------------------------------------

    def create(
        self, robot_id: str, app: App, placement: str | None, reuse: bool, meta: dict[str, Any] | None = None
    ) -> Deployment:
        """Claim an instance (a shared one when `reuse`); creating a new one goes on in the background."""
        if len(self.list(robot_id)) >= self.max_per_robot:
            raise QuotaExceeded(f"robot {robot_id} already has {self.max_per_robot} deployments")
        key = (app.name, placement)
        instance = self._shared.get(key) if reuse else None
        if instance is None or instance.state.phase == FAILED:
            if len(self._instances) >= self.max_netapps:
                raise QuotaExceeded(
                    f"the middleware already runs its limit of {self.max_netapps} NetApps for all robots: "
                    "retry when one is deleted, or ask for a shared one (reuse)"
                )
            instance = Instance(name=instance_name(app.name), app=app.name, placement=placement, shared=reuse)
            self._instances[instance.name] = instance
            if reuse:
                self._shared[key] = instance
            labels = {LABEL_APP: app.name[:63], LABEL_SHARED: str(reuse).lower()}
            spec = render_spec(app, placement)
            if not app.allow_unauthenticated:
                instance.token = self.token_for(instance.name)
                spec = with_token_digest(spec, instance.token)
            self._spawn(self._create_instance(instance, spec, labels))
        else:
            self._spawn(self._record(instance))
        deployment = Deployment(
            id=str(uuid.uuid4()),
            robot_id=robot_id,
            app=app.name,
            placement=placement,
            reuse=reuse,
            instance=instance,
            created_at=time.time(),
            meta=dict(meta or {}),
        )
        instance.claims.add(deployment.id)
        self._deployments[deployment.id] = deployment
        log.info(
            "robot %s: deployment %s of %s on NetApp %s (%d robot(s))",
            robot_id,
            deployment.id,
            app.name,
            instance.name,
            len(instance.claims),
        )
        return deployment

    def get(self, robot_id: str, deployment_id: str) -> Deployment:
        deployment = self._deployments.get(deployment_id)
        if deployment is None or deployment.robot_id != robot_id:
            raise NotFound(deployment_id)
        return deployment

    def overview(self) -> dict[str, Any]:
        """Every NetApp with its robots, and every robot's deployments: what the dashboard shows."""
        robots: dict[str, list[dict[str, Any]]] = {}
        by_instance: dict[str, set[str]] = {}
        for deployment in self._deployments.values():
            if deployment.deleted:
                continue
            robots.setdefault(deployment.robot_id, []).append(deployment.view())
            by_instance.setdefault(deployment.instance.name, set()).add(deployment.robot_id)
        netapps = [
            {
                "name": i.name,
                "app": i.app,
                "placement": i.placement,
                "shared": i.shared,
                "phase": i.state.phase,
                "pool": i.state.pool,
                "url": i.state.url,
                "message": i.state.message,
                "robots": sorted(by_instance.get(i.name, ())),
            }
            for i in self._instances.values()
        ]
        return {"netapps": sorted(netapps, key=lambda n: n["name"]), "robots": robots}

    def list(self, robot_id: str) -> list[Deployment]:
        return [d for d in self._deployments.values() if d.robot_id == robot_id]

    async def wait(self, robot_id: str, deployment_id: str, since: int | None, timeout_s: float) -> Deployment:
        """Return once the deployment's version differs from `since` (default: the current one), it is deleted,
        or `timeout_s` passes; raises NotFound when it does not exist (any more)."""
        deployment = self.get(robot_id, deployment_id)
        target = deployment.instance.version if since is None else since
        deadline = asyncio.get_running_loop().time() + max(0.0, timeout_s)
        while deployment.instance.version == target and not deployment.deleted:
            remaining = deadline - asyncio.get_running_loop().time()
            if remaining <= 0:
                break
            try:
                await asyncio.wait_for(deployment.instance.changed.wait(), remaining)
            except asyncio.TimeoutError:
                break
        if deployment.deleted:
            raise NotFound(deployment_id)
        return deployment

    async def delete(self, robot_id: str, deployment_id: str) -> None:
        """Drop the robot's claim; the last claim on an instance deletes the NetApp (awaited)."""
        deployment = self.get(robot_id, deployment_id)
        del self._deployments[deployment_id]
        deployment.deleted = True
        instance = deployment.instance
        instance.claims.discard(deployment_id)
        instance.notify()
        log.info(
            "robot %s: deleted deployment %s (%d robot(s) left on %s)",
            robot_id,
            deployment_id,
            len(instance.claims),
            instance.name,
        )
        if not instance.claims:
            self._forget(instance)
            await self._delete_instance(instance)
        else:
            self._spawn(self._record(instance))

    # -- backend-facing --------------------------------------------------------------------------------------------

    def report(self, name: str, state: InstanceState) -> None:
        """A backend's news about an instance (ignored for instances already released)."""
        instance = self._instances.get(name)
        if instance is None or state == instance.state:
            return
        log.info("NetApp %s: %s %s %s", name, state.phase, state.url or "", state.message)
        instance.state = state
        instance.version += 1
        if state.phase == READY and state.url:
            instance.last_ready_url = state.url
        instance.notify()

    # -- internals -------------------------------------------------------------------------------------------------

    async def _create_instance(self, instance: Instance, spec: dict[str, Any], labels: dict[str, str]) -> None:
        async with instance.lock:
            try:
                await self.backend.create(instance.name, instance.app, instance.placement, spec, labels)
            except Exception as exc:  # the robot sees the reason in its deployment's message
                log.warning("creating NetApp %s failed: %s", instance.name, exc)
                self.report(instance.name, InstanceState(FAILED, message=f"create failed: {exc}"))
                return
        # Its last robot may have left while the create was in flight: that delete waited for the lock.
        await self._record(instance)

    async def _record(self, instance: Instance) -> None:
        """Store the instance's current claims with it (whatever they are when the lock is ours)."""
        async with instance.lock:
            if instance.name not in self._instances:
                return
            claims = [self._deployments[d].claim() for d in sorted(instance.claims) if d in self._deployments]
            try:
                await self.backend.record(instance.name, claims)
            except Exception as exc:  # the robots' service goes on; only a restart would lose track of them
                log.warning("recording the robots of NetApp %s failed: %s", instance.name, exc)

    async def _delete_instance(self, instance: Instance) -> None:
        async with instance.lock:
            await self.backend.delete(instance.name)

    def _forget(self, instance: Instance) -> None:
        self._instances.pop(instance.name, None)
        key = (instance.app, instance.placement)
        if self._shared.get(key) is instance:
            del self._shared[key]

    def _spawn(self, coro: Any) -> None:
        task = asyncio.get_running_loop().create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)


__all__ = ["Registry", "Deployment", "Instance", "NotFound", "QuotaExceeded", "PENDING", "DEPLOYING", "READY", "FAILED"]
