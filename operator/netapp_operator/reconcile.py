"""The reconcile loop's I/O sequence: plan from pure functions, then apply children, clean up, write status.

The operator's work queue calls `reconcile` for a NetApp whenever it or something it depends on changed; the queue
hands a NetApp to one worker at a time, so a failover and a spec update never apply children for two pools at once.
"""

from __future__ import annotations

import asyncio
import dataclasses
import datetime
import logging
import os
import secrets
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from netapp.tracing import Tracer
from netapp_operator import idle, render, rollout_status, rollouts, status, waker
from netapp_operator.cache import Cache, Key
from netapp_operator.config import OperatorConfig
from netapp_operator.constants import ANNOTATION_MODEL, LABEL_INSTANCE, OPERATOR_MANAGER
from netapp_operator.events import event_manifest
from netapp_operator.kube import CHILD_KINDS, ApiError, Kube
from netapp_operator.placement import Pool, choose_standby, decide
from netapp_operator.spec import NetAppSpec
from netapp_operator.tracing import emit_reconcile
from netapp_operator.watches import MANAGED, WATCHED_CHILDREN, owner

logger = logging.getLogger(__name__)
Child = tuple[str, str]  # (kind, name) of a NetApp's child
CHILD_REJECTED = "ChildRejected"
STANDBY_WARMING, STANDBY_RELEASED = "StandbyWarming", "StandbyReleased"  # Event reasons
FULL_CHECK_EVERY = 12  # periodic passes; one in this many plans every NetApp even when the pools did not change
STANDBY_KINDS = ("Deployment", "Service", "NetworkPolicy")  # what a warm standby is made of (render_standby)


def utcnow() -> datetime.datetime:
    return datetime.datetime.now(datetime.timezone.utc)


@dataclasses.dataclass(frozen=True)
class Plan:
    """What a NetApp should look like now, computed from the cache without any I/O."""

    action: str  # invalid | pending | place | move | stay
    status: dict[str, Any]
    pool: Pool | None = None
    reason: str = ""
    message: str = ""
    standby: Pool | None = None  # where its warm standby waits (spec.standby)


def may_leave_stale(netapp: Mapping[str, Any], new: Mapping[str, Any]) -> bool:
    """Whether a sync writing status `new` may leave children behind: only a NetApp reconciled before, whose pool,
    standby pool or spec (a dropped autoscaler) changed. Looking costs a list per child kind, so a NetApp that is
    just placed, or synced again unchanged, must not look (bench/operator_bench.py: a burst of thousands)."""
    old = netapp.get("status") or {}
    if not (old.get("pool") or old.get("conditions")):
        return False
    return (
        old.get("pool") != new.get("pool")
        or (old.get("standby") or {}).get("pool") != (new.get("standby") or {}).get("pool")
        or old.get("observedGeneration") != netapp["metadata"].get("generation")
    )


def stale_children(
    name: str, spec: NetAppSpec, pool: Pool, standby: Pool | None, children: Iterable[Child]
) -> list[Child]:
    """The children of NetApp `name` that its placement on `pool` (and its standby on `standby`) does not want."""
    keep_name = render.child_name(name, pool.name)
    standby_name = None if standby is None else render.child_name(name, standby.name)
    wanted = {"Deployment", "Service", "NetworkPolicy", "EndpointSlice"}  # the waker's: the reconcile's (_front)
    if spec.autoscaling is not None:
        wanted.add("ScaledObject" if spec.autoscaling.engine == "keda" else "HorizontalPodAutoscaler")
    return [
        (kind, child)
        for kind, child in children
        if not ((child == keep_name and kind in wanted) or (child == standby_name and kind in STANDBY_KINDS))
    ]


class Reconciler:
    def __init__(self, kube: Kube, cache: Cache, config: OperatorConfig, tracer: Tracer | None = None) -> None:
        self.kube = kube
        self.tracer = tracer  # reconciles of NetApps a traced deployment created (docs/tracing.md); None: off
        self.cache = cache
        self.config = config
        # What a restarted operator found of each NetApp's children (find_leftovers): its first reconcile applies
        # the children again (a new operator may render them differently) and removes those it no longer wants.
        self.leftovers: dict[Key, set[Child]] = {}
        self._checked_pools: dict[str, Pool] | None = None  # the pools as the last periodic pass saw them
        self._passes = 0
        self._instance = os.environ.get("HOSTNAME", OPERATOR_MANAGER)
        self.fronts = waker.Fronts(kube, cache, config)  # a sleeping NetApp's Service: the waker's endpoint too

    # --- pure planning over the cache -----------------------------------------------------------------------

    def plan(
        self,
        netapp: Mapping[str, Any],
        spec: NetAppSpec,
        now: datetime.datetime,
        children: Mapping[str, Mapping[str, Any]] | None = None,
    ) -> Plan:
        """The NetApp's placement and status; its Deployment and Service are `children` (by kind, e.g. just
        applied) or else the cache's."""
        meta = netapp["metadata"]
        old = netapp.get("status") or {}
        generation = meta.get("generation")
        found = list(spec.problems)
        if found:
            return Plan(
                "invalid", status.invalid_status(old, found, generation, now), None, "InvalidSpec", "; ".join(found)
            )
        d = decide(
            spec,
            old.get("pool"),
            self.cache.pools(),
            status.pool_unhealthy_since(old),
            now,
            self.config.failover_grace_seconds,
        )
        if d.action == "pending" or d.pool is None:
            return Plan(
                "pending", status.pending_status(old, d.reason, d.message, generation, now), None, d.reason, d.message
            )
        pool = d.pool
        if children is None:
            key = (meta["namespace"], render.child_name(meta["name"], pool.name))
            children = {"Deployment": self.cache.deployments.get(key), "Service": self.cache.services.get(key)}
        deployment = children.get("Deployment")
        url = status.service_url(netapp, spec, pool, children.get("Service"))
        placed = status.find(old.get("conditions"), status.PLACED)
        if d.action in ("place", "move") or placed is None or placed.get("status") != "True":
            placed_reason, placed_message = d.reason, d.message
        else:  # staying: keep saying why it was placed here (e.g. FailedOver) rather than "still here"
            placed_reason, placed_message = placed.get("reason", d.reason), placed.get("message", d.message)
        available = pool.ready_nodes > 0
        pool_message = (
            f"{pool.ready_nodes}/{pool.total_nodes} nodes of NodePool {pool.name!r} are ready"
            if available
            else d.message
        )
        new = status.placed_status(
            old,
            pool=pool.name,
            placed_reason=placed_reason,
            placed_message=placed_message,
            pool_available=available,
            pool_message=pool_message,
            deployment=deployment,
            url=url,
            generation=generation,
            now=now,
        )
        new = idle.with_idle(netapp, new)
        if old.get("rollout"):  # the ModelRollout condition, from what the rollout poller wrote
            new["conditions"] = rollout_status.condition(new["conditions"], old["rollout"], old.get("model"), now)
        standby = choose_standby(spec, pool, self.cache.pools())
        new["standby"] = None if standby is None else self._standby_status(netapp, spec, standby, children)
        return Plan(d.action, new, pool, d.reason, d.message, standby)

    def _standby_status(
        self, netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool, children: Mapping[str, Mapping[str, Any]]
    ) -> dict[str, Any]:
        meta = netapp["metadata"]
        key = (meta["namespace"], render.child_name(meta["name"], pool.name))
        deployment = children.get("standby Deployment") or self.cache.deployments.get(key)
        service = children.get("standby Service") or self.cache.services.get(key)
        requests = render.resource_requests(spec)
        assert spec.standby is not None
        replicas = int(spec.standby.replicas)
        return status.standby_status(
            pool.name, replicas, requests, deployment, status.service_url(netapp, spec, pool, service)
        )

    def _missing(self, namespace: str, name: str, pools: list[Pool | None]) -> bool:
        """Whether a Deployment or Service of the NetApp on one of `pools` is not in the cache."""
        keys = [(namespace, render.child_name(name, pool.name)) for pool in pools if pool is not None]
        return any(key not in self.cache.deployments or key not in self.cache.services for key in keys)

    def _children_gone(self, netapp: Mapping[str, Any]) -> bool:
        """Whether the cache lacks the Deployment or Service of the pool the NetApp's status names."""
        meta, pool = netapp["metadata"], (netapp.get("status") or {}).get("pool")
        key = (meta["namespace"], render.child_name(meta["name"], pool)) if pool else None
        return key is not None and (key not in self.cache.deployments or key not in self.cache.services)

    def needs_sync(self, netapp: Mapping[str, Any], spec: NetAppSpec, now: datetime.datetime) -> bool:
        """Whether anything would change for this NetApp: a (re)placement, a status change, a missing child."""
        meta = netapp["metadata"]
        if meta.get("deletionTimestamp"):
            return False
        old = netapp.get("status") or {}
        placed = status.find(old.get("conditions"), status.PLACED) or {}
        if placed.get("reason") == CHILD_REJECTED and old.get("observedGeneration") == meta.get("generation"):
            return False  # the API server refused this spec; retrying it every check would only spam it
        plan = self.plan(netapp, spec, now)
        if plan.action in ("place", "move") or status.changed(netapp.get("status") or {}, plan.status):
            return True
        if plan.pool is not None:
            stale = self._model_stale(netapp, spec, plan.pool) or self._replicas_stale(netapp, spec, plan.pool)
            stale = stale or self.fronts.stale(netapp, spec, plan.pool)
            return stale or self._missing(meta["namespace"], meta["name"], [plan.pool, plan.standby])
        return False

    def _model_stale(self, netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool) -> bool:
        """Whether the cached Deployment serves another model than the NetApp's `status.model` (a rollout was just
        promoted): it is rendered again, and its pods roll to the new model."""
        if not self.config.rollout_token:
            return False
        meta = netapp["metadata"]
        deployment = self.cache.deployments.get((meta["namespace"], render.child_name(meta["name"], pool.name)))
        if deployment is None:
            return False
        served = render.served_model(rollouts.served_spec(spec, netapp), self.config)
        shown = (deployment["metadata"].get("annotations") or {}).get(ANNOTATION_MODEL)
        return shown != rollouts.model_key(served)

    def _replicas_stale(self, netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool) -> bool:
        """Whether the cached Deployment has other replicas than the NetApp's sleep wants (netapp_operator.idle)."""
        meta = netapp["metadata"]
        deployment = self.cache.deployments.get((meta["namespace"], render.child_name(meta["name"], pool.name)))
        return idle.replicas_stale(netapp, spec, deployment)

    def _record_model(self, netapp: Mapping[str, Any], plan: Plan) -> None:
        """A NetApp placed for the first time (or with no ready replica) records the model it serves: from then on
        a new one is tried by a rollout before its Deployment changes (netapp_operator.rollouts)."""
        if not self.config.rollout_token or plan.pool is None:
            return
        cfg = self.config
        wanted = rollouts.wanted_model(netapp.get("spec") or {}, cfg.default_model_url, cfg.default_model_sha256)
        ready = int(plan.status.get("readyReplicas") or 0)
        model = rollouts.model_to_record(netapp.get("status") or {}, ready, wanted)
        if model is not ...:
            plan.status["model"] = model

    # --- I/O ------------------------------------------------------------------------------------------------

    async def reconcile(self, key: Key) -> None:
        """Bring one NetApp's children and status in line with its spec and the pools' health, as the cache sees
        them now; costs no request when nothing changed (a NetApp handled again, a child's event that changes
        nothing). Level-triggered, so the queue may call it for a key as often as it likes."""
        netapp = self.cache.netapps.get(key)
        if netapp is None:
            return
        known = self.leftovers.pop(key, None)
        if known is None and not self.needs_sync(netapp, self.cache.specs[key], utcnow()):
            return
        if self._children_gone(netapp):
            # Read afresh: a deleted NetApp's children are collected, and their watch events can come before the
            # NetApp's own; it must not get them back. Costs a GET only when children of a placed NetApp vanish.
            fresh = await self.kube.get("NetApp", key[0], key[1])
            if fresh is None:
                return
            self.cache.on_netapp(fresh, deleted=False)
            netapp = self.cache.netapps[key]
        try:
            await self._sync(key[0] or "", key[1], netapp, apply=known is not None, known=known)
        except Exception:
            if known is not None:  # retried later: still a resumed NetApp
                self.leftovers.setdefault(key, known)
            raise

    async def find_leftovers(self, namespaces: Iterable[str | None]) -> None:
        """A restarted operator: note every NetApp's children, from the cache (Deployments, Services) and one
        label-selected list per other kind, instead of five lists per NetApp when each is reconciled."""
        found: dict[Key, set[Child]] = {}

        def note(kind: str, items: Iterable[Mapping[str, Any]]) -> None:
            for item in items:
                key = owner(item)
                if key is not None:
                    found.setdefault(key, set()).add((kind, item["metadata"]["name"]))

        note("Deployment", self.cache.deployments.values())
        note("Service", self.cache.services.values())
        for kind in CHILD_KINDS:
            if kind not in WATCHED_CHILDREN:
                for namespace in namespaces:
                    note(kind, await self._list_children(kind, namespace, MANAGED))
        self.leftovers = found

    async def _sync(
        self, namespace: str, name: str, netapp: Mapping[str, Any], apply: bool, known: set[Child] | None
    ) -> None:
        """`apply` applies the children even if nothing seems to have changed; `known` are children found when
        the operator started (a move may have stopped half-way): those not wanted go once the status is written."""
        if netapp["metadata"].get("deletionTimestamp"):
            return  # deleted: its children go with it through their owner references
        started = time.time_ns()
        old = netapp.get("status") or {}
        now = utcnow()
        spec = self.cache.spec_of(netapp)  # parsed once: placement, render and status read this
        if self.config.rollout_token:  # the model it serves, not a new one a rollout is trying
            spec = rollouts.served_spec(spec, netapp)
        plan = self.plan(netapp, spec, now)
        applied_children = False
        if plan.pool is not None:
            meta = netapp["metadata"]
            missing = self._missing(namespace, meta["name"], [plan.pool, plan.standby])
            stale_spec = old.get("observedGeneration") != meta.get("generation")
            stale_model = self._model_stale(netapp, spec, plan.pool) or self._replicas_stale(netapp, spec, plan.pool)
            if apply or missing or stale_spec or stale_model or plan.action in ("place", "move"):
                try:
                    applied = await self._apply(netapp, spec, plan.pool, plan.standby)
                except ApiError as e:
                    if e.status not in (400, 422):
                        raise
                    # The API server refused a child (a value our checks let through): report it like a
                    # bad spec instead of retrying the same request forever.
                    reason = f"the API server rejected a child of this NetApp: {e.reason}"
                    plan = Plan(
                        "invalid",
                        status.invalid_status(old, [reason], meta.get("generation"), now, CHILD_REJECTED),
                        None,
                        CHILD_REJECTED,
                        reason,
                    )
                    await self._write_status(netapp, old, plan)
                    return
                applied_children = True
                plan = self.plan(netapp, spec, now, children=applied)
        self._record_model(netapp, plan)
        await self._write_status(netapp, old, plan)
        if applied_children or status.changed(old, plan.status):
            attributes = {"netapp.name": name, "netapp.action": plan.action, "netapp.phase": plan.status.get("phase")}
            emit_reconcile(self.tracer, netapp, started, {k: v for k, v in attributes.items() if v})
        if plan.pool is None:
            return
        await self.fronts.sync(netapp, spec, plan.pool, known)  # before the stale children go: it may be one
        # The old children go after the new ones exist and the status points at them.
        if applied_children and may_leave_stale(netapp, plan.status):
            await self._remove_stale(netapp, spec, plan.pool, plan.standby)
        elif known:
            await self._remove(netapp, stale_children(name, spec, plan.pool, plan.standby, known))

    async def _write_status(self, netapp: Mapping[str, Any], old: Mapping[str, Any], plan: Plan) -> None:
        if not status.changed(old, plan.status):
            return
        meta = netapp["metadata"]
        written = await self.kube.patch_status("NetApp", meta["namespace"], meta["name"], plan.status)
        if isinstance(written, dict) and written.get("metadata"):
            # Our own write, now: a child's watch event must not find the cache's older status and sync again
            # (which costs a GET per NetApp; its watch event comes later).
            self.cache.on_netapp(written, deleted=False)
        await self._announce(netapp, old, plan)

    async def check_all(self, enqueue: Callable[[Key], None]) -> None:
        """The periodic pass: queues the NetApps whose plan changed (`due`) and writes the pools' status. Costs no
        API call for a NetApp whose plan has not changed."""
        now = utcnow()
        for key in await self.due(now):
            enqueue(key)
        await self.update_pools(now)

    async def due(self, now: datetime.datetime) -> list[Key]:
        """The NetApps whose plan changed: failover after the grace period, pending NetApps that can now be placed.
        Their own events and their children's queue them otherwise, so only the pools and the clock can change a
        plan here: every NetApp is planned after the pools changed, while a pool has no ready node (a grace period
        may be running), and every FULL_CHECK_EVERY-th pass (a net under the rest); else none (a plan of 5,000
        NetApps costs 120 ms, every pass, bench/operator_bench.py)."""
        pools = self.cache.pools()
        self._passes += 1
        quiet = pools == self._checked_pools and all(p.ready_nodes > 0 for p in pools.values())
        self._checked_pools = pools
        if quiet and self._passes % FULL_CHECK_EVERY:
            return []
        due = []
        for i, (key, netapp) in enumerate(list(self.cache.netapps.items())):
            if self.needs_sync(netapp, self.cache.specs[key], now):
                due.append(key)
            if i % 100 == 99:
                await asyncio.sleep(0)  # thousands of NetApps: let watch events through between slices
        return due

    async def update_pools(self, now: datetime.datetime) -> None:
        for name, pool in self.cache.pools().items():
            body = self.cache.nodepools.get(name)
            if body is None:
                continue
            old = body.get("status") or {}
            ready = pool.ready_nodes > 0
            conditions = status.set_condition(
                old.get("conditions"),
                "Ready",
                ready,
                "NodesReady" if ready else "NoReadyNodes",
                f"{pool.ready_nodes}/{pool.total_nodes} nodes ready",
                now,
            )
            new = {"readyNodes": pool.ready_nodes, "totalNodes": pool.total_nodes, "conditions": conditions}
            if status.changed(old, new):
                try:
                    await self.kube.patch_status("NodePool", None, name, new)
                except ApiError:
                    logger.exception("updating NodePool %s status failed", name)

    async def _create_once(self, manifest: Mapping[str, Any]) -> None:
        """Create a Secret of the NetApp unless it exists: made once, before the Deployment that reads it, and never
        applied again (a reconcile must not rotate a token robots hold, nor the key its replicas share). Create-only,
        so the operator needs no right to read any Secret: 409 says it exists."""
        try:
            await self.kube.create(manifest)
        except ApiError as e:
            if e.status != 409:
                raise
            return
        meta = manifest["metadata"]
        logger.info("created the Secret %s/%s", meta["namespace"], meta["name"])

    async def _apply(
        self, netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool, standby: Pool | None = None
    ) -> dict[str, dict[str, Any]]:
        # Every request at once, the Secrets beside the Deployment that reads them, so a NetApp costs one round trip
        # to the API server, not one per child (bench/operator_bench.py: create -> url). A pod cannot start before
        # the scheduler and a kubelet have seen it, long after the Secrets' create; one failing is retried, and
        # the kubelet retries a pod whose Secret is missing.
        manifests = render.render(netapp, spec, pool, self.config)
        warm = [] if standby is None else render.render_standby(netapp, spec, standby, self.config)
        _, _, *results = await asyncio.gather(
            self._create_once(render.render_token_secret(netapp, secrets.token_urlsafe(32))),
            self._create_once(render.render_cluster_key_secret(netapp, secrets.token_hex(32))),
            *(self.kube.apply(manifest) for manifest in [*manifests, *warm]),
        )
        applied: dict[str, dict[str, Any]] = {}
        for i, (manifest, result) in enumerate(zip([*manifests, *warm], results, strict=True)):
            applied[manifest["kind"] if i < len(manifests) else f"standby {manifest['kind']}"] = result
            # Feed the cache now so that the next check does not see the child as missing before its watch event.
            meta = result.get("metadata", {}) if isinstance(result, dict) else {}
            if meta.get("name"):
                if manifest["kind"] == "Deployment":
                    self.cache.on_deployment(result, deleted=False)
                elif manifest["kind"] == "Service":
                    self.cache.on_service(result, deleted=False)
        return applied

    async def _remove_stale(
        self, netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool, standby: Pool | None = None
    ) -> None:
        meta = netapp["metadata"]
        selector = {**MANAGED, LABEL_INSTANCE: meta["name"]}
        for kind in CHILD_KINDS:
            children = [
                (kind, item["metadata"]["name"])
                for item in await self._list_children(kind, meta["namespace"], selector)
            ]
            await self._remove(netapp, stale_children(meta["name"], spec, pool, standby, children))

    async def _list_children(self, kind: str, namespace: str | None, labels: Mapping[str, str]) -> list[dict[str, Any]]:
        """The operator's children of one kind carrying `labels`; none where KEDA (ScaledObject) is not installed."""
        try:
            return await self.kube.list(kind, namespace, labels)
        except ApiError as exc:
            if exc.status == 404 and kind == "ScaledObject":
                return []
            raise

    async def _remove(self, netapp: Mapping[str, Any], children: Iterable[Child]) -> None:
        meta = netapp["metadata"]
        for kind, name in children:
            if await self.kube.delete(kind, meta["namespace"], name):
                logger.info("removed stale %s %s/%s of NetApp %s", kind, meta["namespace"], name, meta["name"])

    async def _announce(self, netapp: Mapping[str, Any], old: Mapping[str, Any], plan: Plan) -> None:
        """Kubernetes Events for what a user needs to know: placement, failover, why it is not running."""
        if plan.action == "move":
            await self.event(netapp, "Warning", plan.reason, plan.message)
        elif plan.action == "place":
            await self.event(netapp, "Normal", "Placed", plan.message)
        elif plan.action in ("invalid", "pending"):
            before = status.find(old.get("conditions"), status.PLACED)
            if before is None or before.get("reason") != plan.reason or before.get("message") != plan.message:
                await self.event(netapp, "Warning", plan.reason, plan.message)
        was, now = old.get("standby") or {}, plan.status.get("standby") or {}
        if was.get("pool") and was.get("pool") != now.get("pool"):
            await self.event(
                netapp, "Normal", STANDBY_RELEASED, f"the warm standby on NodePool {was['pool']!r} is released"
            )
        if now.get("pool") and was.get("pool") != now.get("pool"):
            cost = ", ".join(f"{k} {v}" for k, v in now.get("requests", {}).items())
            message = (
                f"a warm standby on NodePool {now['pool']!r}: {now['replicas']} replica(s), each requesting {cost}"
            )
            await self.event(netapp, "Normal", STANDBY_WARMING, message)

    async def event(self, obj: Mapping[str, Any], type_: str, reason: str, message: str) -> None:
        meta = obj["metadata"]
        event = event_manifest(
            obj, type_, reason, message, component=OPERATOR_MANAGER, instance=self._instance, now=utcnow()
        )
        try:
            await self.kube.create(event)
        except Exception as e:  # an event is advice; never fail a reconcile over it
            logger.warning("could not post event %s for %s: %s", reason, meta["name"], e)
