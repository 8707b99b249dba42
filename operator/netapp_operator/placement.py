"""Which NodePool a NetApp runs on (pure): pool health from nodes, the placement policy, and failover."""

from __future__ import annotations

import dataclasses
import datetime
from collections.abc import Iterable, Mapping
from typing import Any

from netapp_operator.spec import NetAppSpec, Placement


@dataclasses.dataclass(frozen=True)
class Pool:
    """A NodePool with the health of its nodes, as the placement sees it."""

    name: str
    type: str  # edge | cloud
    gpu: bool
    priority: int
    spec: Mapping[str, Any]
    ready_nodes: int = 0
    total_nodes: int = 0
    addresses: tuple[str, ...] = ()  # addresses of its ready nodes, best first (for NodePort URLs)


@dataclasses.dataclass(frozen=True)
class Choice:
    """The outcome of a placement: a pool, or none with the reason why."""

    pool: Pool | None
    reason: str
    message: str


def node_ready(node: Mapping[str, Any]) -> bool:
    """A node counts when its Ready condition is True and it is not cordoned."""
    if node.get("spec", {}).get("unschedulable"):
        return False
    for cond in node.get("status", {}).get("conditions", []) or []:
        if cond.get("type") == "Ready":
            return cond.get("status") == "True"
    return False


def node_address(node: Mapping[str, Any]) -> str | None:
    """The address robots most likely reach: ExternalIP, then InternalIP, then the host name."""
    by_type = {a.get("type"): a.get("address") for a in node.get("status", {}).get("addresses", []) or []}
    return by_type.get("ExternalIP") or by_type.get("InternalIP") or by_type.get("Hostname")


def selects(selector: Mapping[str, str], labels: Mapping[str, str]) -> bool:
    return all(labels.get(k) == v for k, v in selector.items())


def build_pools(nodepools: Iterable[Mapping[str, Any]], nodes: Iterable[Mapping[str, Any]]) -> dict[str, Pool]:
    """Pools keyed by name, each with its ready and total node counts."""
    nodes = list(nodes)
    pools: dict[str, Pool] = {}
    for np in nodepools:
        spec = np.get("spec", {}) or {}
        selector = spec.get("nodeSelector") or {}
        # An empty selector would select every node: treat such a pool as having none.
        members = [n for n in nodes if selector and selects(selector, n.get("metadata", {}).get("labels") or {})]
        ready = sorted((n for n in members if node_ready(n)), key=lambda n: n.get("metadata", {}).get("name", ""))
        name = np["metadata"]["name"]
        pools[name] = Pool(
            name=name,
            type=spec.get("type", "cloud"),
            gpu=bool(spec.get("gpu", False)),
            priority=int(spec.get("priority", 0) or 0),
            spec=spec,
            ready_nodes=len(ready),
            total_nodes=len(members),
            addresses=tuple(a for a in (node_address(n) for n in ready) if a),
        )
    return pools


def _ranked(pools: Iterable[Pool], type_: str, need_gpu: bool, exclude: Iterable[str]) -> list[Pool]:
    excluded = set(exclude)
    eligible = [
        p for p in pools if p.type == type_ and p.ready_nodes > 0 and (p.gpu or not need_gpu) and p.name not in excluded
    ]
    return sorted(eligible, key=lambda p: (-p.priority, p.name))


def choose_pool(spec: NetAppSpec, pools: Mapping[str, Pool], exclude: Iterable[str] = ()) -> Choice:
    """Pick a pool for a NetApp spec.

    A named pool pins the netapp there even without ready nodes (the user asked for it; pods wait for nodes).
    Policies pick the highest-priority pool with ready nodes (and a GPU when needed); auto tries edge, then cloud.
    """
    need_gpu = spec.requires_gpu
    named = spec.placement.pool
    if named:
        pool = pools.get(named)
        if pool is None:
            return Choice(None, "PoolNotFound", f"NodePool {named!r} does not exist")
        if need_gpu and not pool.gpu:
            return Choice(None, "PoolHasNoGPU", f"NodePool {named!r} offers no GPU but the netapp requires one")
        return Choice(pool, "PoolPinned", f"pinned to NodePool {named!r} ({pool.ready_nodes} ready nodes)")
    policy = spec.placement.policy
    types = {"edge": ["edge"], "cloud": ["cloud"]}.get(policy, ["edge", "cloud"])
    for type_ in types:
        ranked = _ranked(pools.values(), type_, need_gpu, exclude)
        if ranked:
            best = ranked[0]
            how = (
                "edge first"
                if policy == "auto" and type_ == "edge"
                else ("cloud fallback: no edge pool is eligible" if policy == "auto" else f"policy {policy}")
            )
            return Choice(best, "PoolSelected", f"{type_} pool {best.name!r} ({how}; {best.ready_nodes} ready nodes)")
    gpu_note = " with a GPU" if need_gpu else ""
    wanted = " or ".join(types)
    return Choice(None, "NoEligiblePool", f"no {wanted} NodePool{gpu_note} has ready nodes")


@dataclasses.dataclass(frozen=True)
class Decision:
    """What to do with a NetApp now: stay where it is, (re)place it, or wait."""

    action: str  # stay | place | move | pending
    pool: Pool | None
    reason: str
    message: str
    unhealthy_since: datetime.datetime | None = None  # when the current pool lost its last ready node


def decide(
    spec: NetAppSpec,
    current: str | None,
    pools: Mapping[str, Pool],
    unhealthy_since: datetime.datetime | None,
    now: datetime.datetime,
    grace_seconds: float,
) -> Decision:
    """Keep a placed NetApp on its pool while the pool is healthy; move it once the pool has had no ready nodes
    for longer than the grace period and another pool is eligible. Placement is sticky: a recovered edge pool does
    not pull a netapp back from the cloud, because every move changes the robot's URL."""
    named = spec.placement.pool
    if current is None or (named and named != current):
        choice = choose_pool(spec, pools)
        if choice.pool is None:
            return Decision("pending", None, choice.reason, choice.message)
        return Decision("place", choice.pool, choice.reason, choice.message)
    pool = pools.get(current)
    if pool is not None and named:
        return Decision("stay", pool, "PoolPinned", f"pinned to NodePool {current!r} ({pool.ready_nodes} ready nodes)")
    if pool is not None and not _still_eligible(spec, pool):
        choice = choose_pool(spec, pools)
        if choice.pool is not None:
            return Decision(
                "move",
                choice.pool,
                "PlacementChanged",
                f"NodePool {current!r} no longer matches the placement; moved to {choice.pool.name!r}",
            )
        return Decision("pending", None, choice.reason, choice.message)
    if pool is not None and pool.ready_nodes > 0:
        return Decision("stay", pool, "PoolHealthy", f"NodePool {current!r} has {pool.ready_nodes} ready nodes")
    since = unhealthy_since or now
    lost = f"NodePool {current!r} was deleted" if pool is None else f"NodePool {current!r} has no ready nodes"
    waited = (now - since).total_seconds()
    if pool is not None and waited < grace_seconds:
        # No elapsed time in the message: it would change the status (and cost a write) on every check.
        return Decision("stay", pool, "PoolUnavailable", f"{lost}; failover after {grace_seconds:g}s", since)
    choice = choose_pool(spec, pools, exclude=[current])
    if choice.pool is None:
        return Decision(
            "stay" if pool is not None else "pending", pool, "NoFailoverTarget", f"{lost}; {choice.message}", since
        )
    return Decision(
        "move",
        choice.pool,
        "FailedOver",
        f"{lost} (for {waited:.0f}s, grace {grace_seconds:g}s); moved to {choice.pool.name!r}",
        since,
    )


def _still_eligible(spec: NetAppSpec, pool: Pool) -> bool:
    policy = spec.placement.policy
    if policy in ("edge", "cloud") and pool.type != policy:
        return False
    return pool.gpu or not spec.requires_gpu


def choose_standby(spec: NetAppSpec, primary: Pool, pools: Mapping[str, Pool]) -> Pool | None:
    """Where a NetApp's warm standby waits (`spec.standby`): its pinned pool, else the best eligible pool other than
    the NetApp's own, edge first then cloud (with a GPU where the netapp needs one); None without a standby or
    without such a pool."""
    standby = spec.standby
    if standby is None:
        return None
    if standby.pool:
        pool = pools.get(standby.pool)
        return pool if pool is not None and pool.name != primary.name else None
    anywhere = dataclasses.replace(spec, placement=Placement(policy="auto", require_gpu=spec.placement.require_gpu))
    return choose_pool(anywhere, pools, exclude=[primary.name]).pool
