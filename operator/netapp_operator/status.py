"""NetApp status from what the operator observes (pure): conditions, phase, readiness from the Deployment, the URL
from the Service."""

from __future__ import annotations

import dataclasses
import datetime
from collections.abc import Mapping, Sequence
from typing import Any

from netapp_operator.placement import Pool
from netapp_operator.render import child_name
from netapp_operator.spec import NetAppSpec

PLACED, READY, POOL_AVAILABLE = "Placed", "Ready", "PoolAvailable"


def timestamp(now: datetime.datetime) -> str:
    return now.astimezone(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def parse_timestamp(value: str | None) -> datetime.datetime | None:
    if not value:
        return None
    try:
        return datetime.datetime.fromisoformat(value.replace("Z", "+00:00"))
    except ValueError:
        return None


def find(conditions: Sequence[Mapping[str, Any]] | None, type_: str) -> Mapping[str, Any] | None:
    for cond in conditions or []:
        if cond.get("type") == type_:
            return cond
    return None


def set_condition(
    conditions: Sequence[Mapping[str, Any]] | None,
    type_: str,
    status: bool | str,
    reason: str,
    message: str,
    now: datetime.datetime,
) -> list[dict[str, Any]]:
    """A new list with one condition set (`status` a bool, or "Unknown"); lastTransitionTime moves only when the
    status flips."""
    value = status if isinstance(status, str) else "True" if status else "False"
    old = find(conditions, type_)
    since = old.get("lastTransitionTime") if old is not None and old.get("status") == value else None
    new = {
        "type": type_,
        "status": value,
        "reason": reason,
        "message": message,
        "lastTransitionTime": since or timestamp(now),
    }
    out = [dict(c) for c in conditions or [] if c.get("type") != type_]
    out.append(new)
    return sorted(out, key=lambda c: c["type"])


@dataclasses.dataclass(frozen=True)
class Readiness:
    ready: bool
    ready_replicas: int
    reason: str
    message: str
    failed: bool = False  # the rollout cannot make progress (not just slow)
    scaled_to_zero: bool = False


def readiness(deployment: Mapping[str, Any] | None, url: str | None) -> Readiness:
    """Ready follows the Deployment's *available* replicas, so crash-looping pods never count."""
    if deployment is None:
        return Readiness(False, 0, "DeploymentMissing", "the Deployment does not exist yet")
    status = deployment.get("status", {}) or {}
    desired = deployment.get("spec", {}).get("replicas", 1)
    desired = 1 if desired is None else int(desired)
    available = int(status.get("availableReplicas") or 0)
    ready_pods = int(status.get("readyReplicas") or 0)
    for cond in status.get("conditions", []) or []:
        if cond.get("type") == "Progressing" and cond.get("status") == "False":
            return Readiness(
                False,
                ready_pods,
                cond.get("reason") or "ProgressDeadlineExceeded",
                cond.get("message") or "the rollout made no progress",
                failed=True,
            )
    if desired == 0:
        return Readiness(False, 0, "ScaledToZero", "replicas is 0", scaled_to_zero=True)
    if available < desired:
        return Readiness(False, ready_pods, "ReplicasUnavailable", f"{available}/{desired} replicas available")
    if url is None:
        return Readiness(False, ready_pods, "WaitingForAddress", "replicas are available but the URL is not known yet")
    return Readiness(True, ready_pods, "MinimumReplicasAvailable", f"{available}/{desired} replicas available")


def invalid_status(
    old: Mapping[str, Any],
    reasons: Sequence[str],
    generation: int | None,
    now: datetime.datetime,
    reason: str = "InvalidSpec",
) -> dict[str, Any]:
    """Status of a NetApp whose spec cannot be deployed: Failed, with the reasons in both conditions."""
    message = "; ".join(reasons)
    conditions = set_condition(old.get("conditions"), PLACED, False, reason, message, now)
    conditions = set_condition(conditions, READY, False, reason, message, now)
    return {
        "phase": "Failed",
        "conditions": conditions,
        "readyReplicas": 0,
        "observedGeneration": generation,
        "pool": old.get("pool"),
        "url": old.get("url"),
    }


def pending_status(
    old: Mapping[str, Any], reason: str, message: str, generation: int | None, now: datetime.datetime
) -> dict[str, Any]:
    conditions = set_condition(old.get("conditions"), PLACED, False, reason, message, now)
    conditions = set_condition(conditions, READY, False, reason, message, now)
    # None deletes the keys in a merge patch: a netapp without a pool has no URL to give out.
    return {
        "phase": "Pending",
        "conditions": conditions,
        "readyReplicas": 0,
        "observedGeneration": generation,
        "pool": None,
        "url": None,
    }


def placed_status(
    old: Mapping[str, Any],
    *,
    pool: str,
    placed_reason: str,
    placed_message: str,
    pool_available: bool,
    pool_message: str,
    deployment: Mapping[str, Any] | None,
    url: str | None,
    generation: int | None,
    now: datetime.datetime,
) -> dict[str, Any]:
    """Status of a placed NetApp: Placed, PoolAvailable (its lastTransitionTime times failover) and Ready."""
    state = readiness(deployment, url)
    conditions = set_condition(old.get("conditions"), PLACED, True, placed_reason, placed_message, now)
    conditions = set_condition(
        conditions,
        POOL_AVAILABLE,
        pool_available,
        "NodesReady" if pool_available else "NoReadyNodes",
        pool_message,
        now,
    )
    conditions = set_condition(conditions, READY, state.ready, state.reason, state.message, now)
    if state.failed:
        phase = "Failed"
    elif state.ready:
        phase = "Ready"
    elif state.scaled_to_zero:
        phase = "Pending"
    else:
        phase = "Deploying"
    return {
        "phase": phase,
        "conditions": conditions,
        "pool": pool,
        "url": url,
        "readyReplicas": state.ready_replicas,
        "observedGeneration": generation,
    }


def standby_status(
    pool: str, replicas: int, requests: Mapping[str, Any], deployment: Mapping[str, Any] | None, url: str | None
) -> dict[str, Any]:
    """`status.standby`: where the warm standby waits, whether it is ready, and what it costs (requests per replica)."""
    state = readiness(deployment, url)
    return {
        "pool": pool,
        "url": url,
        "replicas": replicas,
        "readyReplicas": state.ready_replicas,
        "ready": state.ready,
        "requests": {k: str(v) for k, v in requests.items() if k in ("cpu", "memory", "nvidia.com/gpu")},
    }


def pool_unhealthy_since(status: Mapping[str, Any]) -> datetime.datetime | None:
    """When the current pool lost its last ready node, from the PoolAvailable condition (survives restarts)."""
    cond = find(status.get("conditions"), POOL_AVAILABLE)
    if cond is None or cond.get("status") != "False":
        return None
    return parse_timestamp(cond.get("lastTransitionTime"))


def changed(old: Mapping[str, Any], new: Mapping[str, Any]) -> bool:
    """Whether writing `new` would change anything (avoids a status write, and a watch event, per check)."""
    return any(old.get(k) != v for k, v in new.items())


def service_url(
    netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool, service: Mapping[str, Any] | None
) -> str | None:
    """The URL a robot uses to reach the netapp in its pool, from the observed Service, or None while it is not
    known yet (e.g. a NodePort not yet allocated or a LoadBalancer without an address)."""
    meta = netapp["metadata"]
    access = pool.spec.get("access") or {}
    service_type = access.get("serviceType", "NodePort")
    port = int(spec.port)
    svc_name = child_name(meta["name"], pool.name)
    node_port: int | None = None
    lb_host: str | None = None
    if service is not None:
        for p in service.get("spec", {}).get("ports", []) or []:
            if p.get("name") == "http" or node_port is None:
                node_port = p.get("nodePort") or node_port
        for ingress in service.get("status", {}).get("loadBalancer", {}).get("ingress", []) or []:
            lb_host = ingress.get("hostname") or ingress.get("ip")
            if lb_host:
                break
    if service_type == "NodePort":
        host = access.get("host") or (pool.addresses[0] if pool.addresses else None)
        if node_port is None:
            return None
    elif service_type == "LoadBalancer":
        host = lb_host or access.get("host")
    else:
        host = access.get("host") or f"{svc_name}.{meta['namespace']}.svc.cluster.local"
    template = access.get("urlTemplate")
    fields = {
        "host": host,
        "port": port,
        "nodePort": node_port,
        "name": meta["name"],
        "namespace": meta["namespace"],
        "service": svc_name,
        "pool": pool.name,
        "scheme": "https" if spec.tls is not None else "http",
    }
    if template:
        needed = {f for f in fields if "{" + f + "}" in template}
        if any(fields[f] is None for f in needed):
            return None
        return template.format(**fields)
    if host is None:
        return None
    return f"{fields['scheme']}://{host}:{node_port if service_type == 'NodePort' else port}"
