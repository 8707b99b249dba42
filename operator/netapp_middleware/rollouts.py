"""A NetApp's `spec.rollout` (or a new `spec.model`) as the request that starts a rollout on its running netapp:
`POST /rollout` (docs/rollouts.md). Pure."""

from __future__ import annotations

from typing import Any

# spec.rollout's fields -> POST /rollout's
FIELDS = {
    "promoteAfter": "promote_after",
    "minAgreement": "min_agreement",
    "maxSlowdown": "max_slowdown",
    "canaryShare": "canary_share",
    "shadowSample": "shadow_sample",
    "shadowBudget": "shadow_budget",
}


def rollout_request(spec: dict[str, Any]) -> dict[str, Any]:
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
