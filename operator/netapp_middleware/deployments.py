"""Robots' deployments and the NetApp instances behind them.

A deployment is one robot's claim on an instance; with reuse, robots asking for the same app and placement claim
the same instance (1:n) and the instance is deleted when its last claim goes. Everything here runs on the event
loop, so no locks: a backend reports state changes through `report`, and waiters are woken by an asyncio.Event.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
import uuid
from collections.abc import Callable, Sequence
from typing import Any

from netapp_operator.constants import ANNOTATION_TRACEPARENT, LABEL_APP, LABEL_SHARED

from .backends.base import DEPLOYING, FAILED, IDLE, PENDING, READY, Backend, InstanceState
from .catalogue import App, render_spec
from .instances import Deployment, Instance, hold_record, is_warm, robot_claims, warm_claim, with_token_digest
from .priorities import class_tokens, with_class_tokens
from .rollouts import serving_key
from .tracing import DeploymentTrace

log = logging.getLogger(__name__)


class NotFound(Exception):
    """No such deployment for this robot (another robot's deployment is reported the same way)."""


class QuotaExceeded(Exception):
    """The robot already has as many deployments as it may."""


class Unrunnable(ValueError):
    """The backend cannot run the app's NetApp as its spec says: one line that names the field."""


def instance_name(app: str) -> str:
    """A DNS-1123 NetApp name: the app's name (trimmed) and a random suffix."""
    stem = "".join(c if c.isalnum() else "-" for c in app.lower()).strip("-")[:50] or "netapp"
    return f"{stem}-{secrets.token_hex(4)}"


class Registry:
    """Creates, shares, follows, moves and deletes deployments on one backend."""

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
                class_tokens=class_tokens(found.name, self.token_for),
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
                instance.claims.add(claim.deployment_id)
                if is_warm(claim.deployment_id):  # a standby's or a route's hold: `holds` gives it to Following
                    continue
                deployment = self._deployments.get(claim.deployment_id)
                if deployment is not None:  # a hedged deployment's other instance
                    deployment.instances.append(instance)
                    order = deployment.hedge or []
                    deployment.instances.sort(key=lambda i: order.index(i.placement) if i.placement in order else 99)
                else:
                    self._deployments[claim.deployment_id] = Deployment(
                        id=claim.deployment_id,
                        robot_id=claim.robot_id,
                        app=found.app,
                        placement=claim.placement,
                        reuse=claim.reuse,
                        instances=[instance],
                        created_at=claim.created_at,
                        meta=dict(claim.meta),
                    )
            log.info(
                "took back NetApp %s (%s) with %d robot deployment(s) and %d warm hold(s)",
                found.name,
                found.state.phase,
                robot_claims(instance.claims),
                len(instance.claims) - robot_claims(instance.claims),
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
        self,
        robot_id: str,
        app: App,
        placement: str | None,
        reuse: bool,
        meta: dict[str, Any] | None = None,
        hedge: Sequence[str] | None = None,
        trace: DeploymentTrace | None = None,
    ) -> Deployment:
        """Claim an instance (a shared one when `reuse`), or one on each placement of `hedge` (the first is the
        primary); creating a new one goes on in the background. `trace`: the request's, when sampled."""
        if len(self.list(robot_id)) >= self.max_per_robot:
            raise QuotaExceeded(f"robot {robot_id} already has {self.max_per_robot} deployments")
        meta = dict(meta or {})
        if app.channel is not None:  # what the robot is given as its netapp's address (Deployment.address)
            meta["channel"] = app.channel.robot_url
        placements: list[str | None] = [placement]
        if hedge:
            placements = list(dict.fromkeys(hedge))
            placement = placements[0]
            meta["hedge"] = placements
        self._check_runnable(app, placements)
        self._check_capacity(app, placements, reuse)
        deployment = Deployment(
            id=str(uuid.uuid4()),
            robot_id=robot_id,
            app=app.name,
            placement=placement,
            reuse=reuse,
            instances=[self._claim_instance(app, p, reuse, trace) for p in placements],
            created_at=time.time(),
            meta=meta,
            trace=trace,
        )
        self._deployments[deployment.id] = deployment
        for instance in deployment.instances:
            instance.claims.add(deployment.id)
            log.info(
                "robot %s: deployment %s of %s on NetApp %s (%s, %d robot(s))",
                robot_id,
                deployment.id,
                app.name,
                instance.name,
                instance.placement,
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
            for instance in deployment.instances:  # a hedged deployment's robot uses each of them
                by_instance.setdefault(instance.name, set()).add(deployment.robot_id)
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

    def instances(self) -> list[Instance]:
        """Every NetApp instance, whatever its phase."""
        return list(self._instances.values())

    def exists(self, deployment_id: str) -> bool:
        return deployment_id in self._deployments

    def live(self) -> list[Deployment]:
        """Every robot's deployment."""
        return list(self._deployments.values())

    def holds(self) -> dict[tuple[str, str], Instance]:
        """The instances held warm (`hold`), by (app, placement): those taken back at `start` included."""
        return {
            (i.app, str(i.placement)): i
            for i in self._instances.values()
            if warm_claim(i.app, str(i.placement)) in i.claims
        }

    def record(self, deployment: Deployment) -> None:
        """Store the deployment's claim anew with each of its instances (its `meta` changed)."""
        for instance in deployment.instances:
            self._spawn(self._record(instance))

    def warm_placements(self, app: str) -> set[str]:
        """The placements where a shared netapp of `app` is Ready: a robot moved there starts nothing."""
        return {str(p) for (a, p), i in self._shared.items() if a == app and i.state.phase == READY and i.state.url}

    def list(self, robot_id: str) -> list[Deployment]:
        return [d for d in self._deployments.values() if d.robot_id == robot_id]

    async def wait(self, robot_id: str, deployment_id: str, since: int | None, timeout_s: float) -> Deployment:
        """Return once the deployment's version differs from `since` (default: the current one), it is deleted,
        or `timeout_s` passes; raises NotFound when it does not exist (any more)."""
        deployment = self.get(robot_id, deployment_id)
        target = deployment.version if since is None else since
        await self._until(deployment, lambda: deployment.version != target, timeout_s)
        if deployment.deleted:
            raise NotFound(deployment_id)
        return deployment

    async def delete(self, robot_id: str, deployment_id: str) -> None:
        """Drop the robot's claims; the last claim on an instance deletes the NetApp (awaited)."""
        deployment = self.get(robot_id, deployment_id)
        del self._deployments[deployment_id]
        deployment.deleted = True
        log.info("robot %s: deleted deployment %s", robot_id, deployment_id)
        await asyncio.gather(*(self.release(deployment, instance) for instance in deployment.instances))

    async def move(self, deployment: Deployment, app: App, placement: str, timeout_s: float) -> Instance | None:
        """Make before break: claim an instance on `placement`, wait until it is Ready, then point the deployment at
        it (its URL and version change, so a following robot switches). Returns the old instance, still claimed:
        the caller `release`s it once the robot has moved; None when the new one failed or was not Ready in time
        (the robot stays where it is)."""
        if len(deployment.instances) != 1 or deployment.moving:
            raise ValueError("only a deployment on one instance, not already moving, can be moved")
        self._check_runnable(app, [placement])
        self._check_capacity(app, [placement], deployment.reuse)
        deployment.moving = True
        try:
            new = self._claim_instance(app, placement, deployment.reuse)
            new.claims.add(deployment.id)
            deadline = asyncio.get_running_loop().time() + timeout_s
            while new.state.phase != READY or not new.state.url:
                remaining = deadline - asyncio.get_running_loop().time()
                if new.state.phase == FAILED or remaining <= 0 or deployment.deleted:
                    await self.release(deployment, new)
                    return None
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(new.changed.wait(), remaining)
            if deployment.deleted:  # the robot left while the new one started
                await self.release(deployment, new)
                return None
            old = deployment.instance
            before = deployment.version
            deployment.instances = [new]
            deployment.placement = placement
            deployment.version_base = before + 1 - new.version
            deployment.arrived_at = time.time()
            self._spawn(self._record(new))  # the claim's placement is the new one
            old.notify()  # wakes the robot's long poll, which now sees the new instance
            return old
        finally:
            deployment.moving = False

    # -- backend-facing --------------------------------------------------------------------------------------------

    def report(self, name: str, state: InstanceState) -> None:
        """A backend's news about an instance (ignored for instances already released)."""
        instance = self._instances.get(name)
        if instance is None or state == instance.state:
            return
        log.info("NetApp %s: %s %s %s", name, state.phase, state.url or "", state.message)
        if state.phase == READY and not instance.ready_ns:
            instance.ready_ns = time.monotonic_ns()
        instance.state = state
        instance.version += 1
        if state.phase == READY and state.url:
            instance.last_ready_url = state.url
        instance.notify()

    # -- internals -------------------------------------------------------------------------------------------------

    def _reusable(self, app: App, placement: str | None, reuse: bool) -> Instance | None:
        instance = self._shared.get((app.name, placement)) if reuse else None
        return None if instance is None or instance.state.phase == FAILED else instance

    def _check_runnable(self, app: App, placements: Sequence[str | None]) -> None:
        """Raise Unrunnable when the backend cannot run the app's spec as it says (`Backend.refuse`), before
        anything is claimed: a robot learns why at once, not from a deployment that never comes up."""
        refuse = getattr(self.backend, "refuse", None)
        for placement in placements if callable(refuse) else ():
            refused = refuse(render_spec(app, placement))
            if refused is not None:
                raise Unrunnable(f"app {app.name!r} cannot run on the {self.backend.name} backend: {refused}")

    def _check_capacity(self, app: App, placements: Sequence[str | None], reuse: bool) -> None:
        """Raise QuotaExceeded unless the NetApps these placements need fit under `max_netapps` (all or none)."""
        needed = sum(1 for p in placements if self._reusable(app, p, reuse) is None)
        if needed and len(self._instances) + needed > self.max_netapps:
            raise QuotaExceeded(
                f"the middleware already runs its limit of {self.max_netapps} NetApps for all robots: "
                "retry when one is deleted, or ask for a shared one (reuse)"
            )

    def _claim_instance(
        self, app: App, placement: str | None, reuse: bool, trace: DeploymentTrace | None = None
    ) -> Instance:
        """The shared instance of (app, placement) when `reuse` and one is alive, else a new one (being created,
        annotated with `trace`'s traceparent); callers `_check_capacity` first."""
        instance = self._reusable(app, placement, reuse)
        if instance is None:
            instance = Instance(
                name=instance_name(app.name), app=app.name, placement=placement, shared=reuse, trace=trace
            )
            self._instances[instance.name] = instance
            if reuse:
                self._shared[(app.name, placement)] = instance
            labels = {LABEL_APP: app.name[:63], LABEL_SHARED: str(reuse).lower()}
            spec = render_spec(app, placement, instance.name)
            instance.model_key = serving_key(spec)
            if not app.allow_unauthenticated:
                instance.token = self.token_for(instance.name)
                spec = with_token_digest(spec, instance.token)
            instance.class_tokens = class_tokens(instance.name, self.token_for)
            spec = with_class_tokens(spec, instance.class_tokens)
            annotations = {ANNOTATION_TRACEPARENT: trace.traceparent()} if trace is not None else {}
            self._spawn(self._create_instance(instance, spec, labels, annotations))
        else:
            self._spawn(self._record(instance))
            if instance.state.phase == IDLE or (app.spec.get("scaling") or {}).get("idleToZero"):  # a robot comes
                self.wake(instance)
        return instance

    def wake(self, instance: Instance) -> None:
        """Bring an instance asleep at zero replicas back (`Backend.wake`), or keep an awake one from sleeping
        before its new robot connects; the robot's request is held until it is Ready (`settled`)."""
        if callable(getattr(self.backend, "wake", None)):
            self._spawn(self._wake(instance))

    async def _wake(self, instance: Instance) -> None:
        async with instance.lock:
            if instance.name not in self._instances:
                return
            try:
                await self.backend.wake(instance.name)  # type: ignore[attr-defined]
            except Exception as exc:  # shown in its deployments' message; the robot's next request tries again
                log.warning("waking NetApp %s failed: %s", instance.name, exc)

    async def settled(self, deployment: Deployment, timeout_s: float) -> Deployment:
        """The deployment once each of its instances is Ready or Failed, or when `timeout_s` passed: a robot's
        request held until it can be answered with a URL rather than with a phase to wait on."""
        instances = deployment.instances
        await self._until(
            deployment,
            lambda: all(i.state.phase == FAILED or i.state.phase == READY and i.state.url for i in instances),
            timeout_s,
        )
        return deployment

    @staticmethod
    async def _until(deployment: Deployment, done: Callable[[], bool], timeout_s: float) -> None:
        """Wait until `done()`, the deployment is deleted or `timeout_s` passed, waking on its instances' news."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + max(0.0, timeout_s)
        while not deployment.deleted and not done():
            remaining = deadline - loop.time()
            if remaining <= 0:
                break
            waits = [asyncio.ensure_future(i.changed.wait()) for i in deployment.instances]
            try:
                await asyncio.wait(waits, timeout=remaining, return_when=asyncio.FIRST_COMPLETED)
            finally:
                for waiter in waits:
                    waiter.cancel()

    def hold(self, app: App, placement: str) -> Instance:
        """Keep the shared instance of (app, placement) warm for robots that may come (a standby, a robot's route):
        claimed by `warm:<app>:<placement>`, no robot's deployment; `release_claim` lets it go. Raises
        QuotaExceeded or Unrunnable."""
        self._check_runnable(app, [placement])
        self._check_capacity(app, [placement], True)
        instance = self._claim_instance(app, placement, True)
        instance.claims.add(warm_claim(app.name, placement))
        return instance

    async def release(self, deployment: Deployment, instance: Instance) -> None:
        """Drop the deployment's claim on `instance`; deleting the NetApp with its last claim (awaited)."""
        await self.release_claim(deployment.id, instance)

    async def release_claim(self, claim: str, instance: Instance) -> None:
        """Drop a claim (a deployment's id, or a warm hold's) on `instance`; the last one deletes the NetApp."""
        if claim not in instance.claims:
            return
        instance.claims.discard(claim)
        instance.notify()
        log.info("%s left NetApp %s (%d robot(s) left)", claim, instance.name, robot_claims(instance.claims))
        if not instance.claims:
            self._forget(instance)
            await self._delete_instance(instance)
        else:
            self._spawn(self._record(instance))

    async def _create_instance(
        self, instance: Instance, spec: dict[str, Any], labels: dict[str, str], annotations: dict[str, str]
    ) -> None:
        async with instance.lock:
            instance.create_started_ns = time.monotonic_ns()
            try:
                await self.backend.create(instance.name, instance.app, instance.placement, spec, labels, annotations)
            except Exception as exc:  # the robot sees the reason in its deployment's message
                log.warning("creating NetApp %s failed: %s", instance.name, exc)
                self.report(instance.name, InstanceState(FAILED, message=f"create failed: {exc}"))
                return
            finally:
                instance.create_done_ns = time.monotonic_ns()
        # Its last robot may have left while the create was in flight: that delete waited for the lock.
        await self._record(instance)

    async def _record(self, instance: Instance) -> None:
        """Store the instance's current claims with it (whatever they are when the lock is ours)."""
        async with instance.lock:
            if instance.name not in self._instances:
                return
            claims = [self._deployments[d].claim() for d in sorted(instance.claims) if d in self._deployments]
            claims += [hold_record(c, instance.placement) for c in sorted(instance.claims) if is_warm(c)]
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
