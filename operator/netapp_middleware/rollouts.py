"""A NetApp's `spec.rollout` (or a new `spec.model`) as the request that starts a rollout on its running netapp:
`POST /rollout` (docs/rollouts.md); which model a spec asks for, and the one line that tells a rollout's outcome.
Pure."""

from __future__ import annotations

from typing import Any

# One builder of the request, the operator's and this one's (netapp_operator.rollouts)
from netapp_operator.rollout_plan import PROMOTED, REFUSED, ROLLED_BACK
from netapp_operator.rollouts import EVENT_PROMOTED, EVENT_ROLLED_BACK, rollout_request

# A NetApp's model as the catalogue names it: (model or candidate, its sha256 or "").
ModelKey = tuple[str, str]

# Events (a log line on the local backend), one per rollout's outcome
EVENT_REFUSED = "RolloutRefused"
# What the middleware's API shows of a netapp's GET /rollout (docs/rollouts.md)
SHOWN = ("phase", "model", "serving", "reason", "agreement", "frames_compared", "p95_ms", "errors", "started_at")


def serving_key(spec: dict[str, Any]) -> ModelKey | None:
    """The model a netapp started from `spec` serves (`spec.model`); None when it names none."""
    model = spec.get("model") or {}
    url = model.get("url")
    return (url, str(model.get("sha256") or "")) if isinstance(url, str) and url else None


def candidate_key(spec: dict[str, Any]) -> ModelKey | None:
    """The model `spec` asks its netapp to serve next: `rollout.candidate`, else `model`; None when none. A running
    netapp whose model key differs from it gets a rollout of it."""
    try:
        body = rollout_request(spec)
    except ValueError:
        return None
    return body["candidate"], str(body.get("sha256") or "")


def rollout_summary(state: dict[str, Any]) -> dict[str, Any]:
    """What the middleware shows of a netapp's `GET /rollout` answer: the known fields only."""
    return {name: state[name] for name in SHOWN if name in state}


def outcome_event(app: str, state: dict[str, Any]) -> tuple[str, str, str] | None:
    """The Event (type, reason, message) for a rollout's state, None until it has a verdict: the one line a person
    reads to know whether the new model serves, and why."""
    model, reason = state.get("model"), state.get("reason") or "no reason given"
    if state.get("phase") == PROMOTED:
        agreement = state.get("agreement")
        shown = f" (agreement {agreement:.3f})" if isinstance(agreement, (int, float)) else ""
        return "Normal", EVENT_PROMOTED, f"{app}: rollout of {model} promoted: {reason}{shown}"
    if state.get("phase") == ROLLED_BACK:
        serving = state.get("serving")
        return "Warning", EVENT_ROLLED_BACK, f"{app}: rollout of {model} rolled back: {reason}; serving {serving}"
    if state.get("phase") == REFUSED:
        return "Warning", EVENT_REFUSED, f"{app}: rollout of {model} not started: {reason}"
    return None
