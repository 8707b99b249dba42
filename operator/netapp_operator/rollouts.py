"""Model rollouts of a NetApp (pure, docs/rollouts.md#kubernetes): which model it should serve, which it serves,
the `POST /rollout` body that tries the one on the other, and its `status.rollout` from the netapp's `GET /rollout`.

A NetApp that has been placed records in `status.model` the model its Deployment serves. A new `spec.model` (or
`spec.rollout.candidate`) does not change the Deployment: the operator starts a shadow on one ready pod of it, and
only a promotion writes the candidate into `status.model`, which the next reconcile renders (pods roll, one at a
time, maxUnavailable 0). A rollback leaves `status.model` as it was. The middleware's local backend builds its
`POST /rollout` body here too (`rollout_request`).
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Mapping
from typing import Any

from netapp_operator import rollout_plan
from netapp_operator.rollout_plan import Attempt, stage_of
from netapp_operator.spec import MODEL_TIMEOUT_S, Model, NetAppSpec

# spec.rollout's fields -> POST /rollout's
FIELDS = {
    "promoteAfter": "promote_after",
    "minAgreement": "min_agreement",
    "maxSlowdown": "max_slowdown",
    "canaryShare": "canary_share",
    "shadowSample": "shadow_sample",
    "shadowBudget": "shadow_budget",
}
FINISHED = ("Promoted", "RolledBack")
EVENT_PROMOTED, EVENT_ROLLED_BACK = "RolloutPromoted", "RolloutRolledBack"  # Event reasons, operator and middleware


def rollout_request(spec: Mapping[str, Any]) -> dict[str, Any]:
    """The body of `POST /rollout` for `spec`: its `rollout.candidate`, else its `model.url` (a changed model is
    tried as a candidate), with `rollout`'s judging fields; ValueError, one line, when it names no candidate."""
    rollout = spec.get("rollout") or {}
    model = spec.get("model") or {}
    candidate = rollout.get("candidate") or model.get("url")
    if not isinstance(candidate, str) or not candidate:
        raise ValueError("a rollout needs spec.rollout.candidate or spec.model.url: the model to try")
    body: dict[str, Any] = {"candidate": candidate}
    sha256 = rollout.get("sha256") if rollout.get("candidate") else model.get("sha256")
    if sha256:
        body["sha256"] = sha256
    body.update({wire: rollout[name] for name, wire in FIELDS.items() if name in rollout})
    return body


def wanted_model(spec: Mapping[str, Any], default_url: str = "", default_sha256: str = "") -> dict[str, Any] | None:
    """The model `spec` asks its netapp to serve, as `status.model` records it: `rollout.candidate`, else `model`
    (its url and sha256, or its volume), else the operator's default; None for a processor with its own weights."""
    processor = spec.get("processor")
    if isinstance(processor, str) and ":" in processor:
        return None
    rollout, model = spec.get("rollout") or {}, spec.get("model") or {}
    if rollout.get("candidate"):
        url, sha256 = rollout["candidate"], rollout.get("sha256")
    elif model.get("volume"):
        return {"volume": dict(model["volume"])}
    elif model.get("url"):
        url, sha256 = model["url"], model.get("sha256")
    elif default_url:
        url, sha256 = default_url, default_sha256
    else:
        return None
    return {"url": url, **({"sha256": str(sha256).lower()} if sha256 else {})}


def served_model(netapp: Mapping[str, Any], wanted: Mapping[str, Any] | None) -> Mapping[str, Any] | None:
    """The model the NetApp's Deployment serves: `status.model` once it is placed, else the one its spec wants."""
    status = netapp.get("status") or {}
    return status["model"] if "model" in status else wanted


def served_spec(spec: NetAppSpec, netapp: Mapping[str, Any]) -> NetAppSpec:
    """`spec` with the model the NetApp serves (`status.model`) in place of the one it asks for: what its
    Deployment renders while a new model is tried, or after one was rolled back."""
    served = (netapp.get("status") or {}).get("model")
    if not served:
        return spec
    timeout = spec.model.timeout_seconds if spec.model is not None else MODEL_TIMEOUT_S
    volume = served.get("volume")
    if volume:
        model = Model(volume_claim=volume.get("claimName"), volume_path=volume.get("path"), has_volume=True)
    else:
        model = Model(url=served.get("url"), sha256=served.get("sha256"), timeout_seconds=timeout)
    return dataclasses.replace(spec, model=model)


def model_key(model: Mapping[str, Any] | None) -> str:
    """One string for a model (the Deployment's annotation, to see it is rendered): its url, else its volume."""
    if not model:
        return ""
    if model.get("url"):
        return str(model["url"]) + (f"#sha256={model['sha256']}" if model.get("sha256") else "")
    volume = model.get("volume") or {}
    return f"pvc:{volume.get('claimName')}/{volume.get('path')}"


def model_to_record(status: Mapping[str, Any], ready_replicas: int, wanted: Mapping[str, Any] | None) -> Any:
    """What a reconcile writes into `status.model` (a NetApp placed for the first time, or one with no ready replica:
    nothing serves that a candidate could be compared with, so its pods take the new model at once), else `...`
    for no change. After that only a promoted rollout changes it."""
    if "model" not in status or (ready_replicas == 0 and status["model"] != wanted):
        return wanted
    return ...


def attempt(rollout: Mapping[str, Any] | None) -> Attempt | None:
    """`status.rollout` as the planner reads it (netapp_operator.rollout_plan); None without one."""
    if not rollout:
        return None
    return Attempt(target=rollout.get("target"), stage=stage_of(rollout.get("phase")), on=rollout.get("pod"))


def next_step(netapp: Mapping[str, Any], wanted: Mapping[str, Any] | None, rollout: Mapping[str, Any] | None) -> str:
    """What the operator does next on the NetApp's rollout (`rollout_plan.next_step`), last seen as `rollout`: it is
    ready once placed with a model recorded and a ready replica; `wanted` is tried only with a url (a volume's file
    is not in the running pods)."""
    status = netapp.get("status") or {}
    ready = bool(status.get("pool") and status.get("readyReplicas") and "model" in status)
    triable = wanted if wanted and wanted.get("url") else None
    return rollout_plan.next_step(triable, status.get("model"), ready, attempt(rollout))


def active(netapp: Mapping[str, Any], wanted: Mapping[str, Any] | None) -> bool:
    """Whether a rollout is to start or under way, from the NetApp's own `status.rollout`."""
    return next_step(netapp, wanted, (netapp.get("status") or {}).get("rollout")) != rollout_plan.LEAVE


def ready_pod(pods: list[Mapping[str, Any]], labels: Mapping[str, str]) -> Mapping[str, Any] | None:
    """The pod to run the shadow on: the first by name of the ready, running pods carrying `labels` (the
    Deployment's, not its standby's) with an IP; None while there is none."""
    for pod in sorted(pods, key=lambda p: p["metadata"]["name"]):
        if pod_ready(pod) and all((pod["metadata"].get("labels") or {}).get(k) == v for k, v in labels.items()):
            return pod
    return None


def pod_ready(pod: Mapping[str, Any] | None) -> bool:
    """Whether `pod` runs, is Ready, has an IP and is not going away."""
    if not pod or pod["metadata"].get("deletionTimestamp"):
        return False
    status = pod.get("status") or {}
    ready = any(c.get("type") == "Ready" and c.get("status") == "True" for c in status.get("conditions") or [])
    return ready and status.get("phase") == "Running" and bool(status.get("podIP"))


def pod_url(pod: Mapping[str, Any], port: int, tls: bool) -> str:
    """The netapp of `pod`, straight (not through the Service: a rollout is one replica's)."""
    ip = pod["status"]["podIP"]
    host = f"[{ip}]" if ":" in ip else ip
    return f"{'https' if tls else 'http'}://{host}:{port}"


def token_digest(token: str) -> str:
    """What the netapp's NETAPP_ADMIN_TOKEN_SHA256 holds for the operator's rollout token."""
    return hashlib.sha256(token.encode()).hexdigest()
