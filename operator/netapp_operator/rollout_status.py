"""A NetApp's `status.rollout`, its ModelRollout condition and its Events (pure), from what the operator saw of
the rollout on its netapp (`GET /rollout`, docs/rollouts.md#kubernetes)."""

from __future__ import annotations

import datetime
from collections.abc import Mapping
from typing import Any

from netapp_operator.rollouts import EVENT_PROMOTED, EVENT_ROLLED_BACK, FINISHED, model_key
from netapp_operator.status import set_condition, timestamp

# the netapp's GET /rollout phase -> status.rollout.phase
PHASES = {"shadow": "Shadow", "canary": "Canary", "promoted": "Promoted", "rolled_back": "RolledBack"}
_NETAPP_PHASES = {phase: wire for wire, phase in PHASES.items()}
PENDING = "Pending"  # no shadow runs yet: waiting for a ready pod, or its netapp could not be reached
CONDITION = "ModelRollout"  # True: promoted; False: rolled back; Unknown while it runs


def pending(target: Mapping[str, Any], reason: str, now: datetime.datetime) -> dict[str, Any]:
    """`status.rollout` of a rollout that waits (for a ready pod, for its netapp to answer), with why."""
    return {
        "phase": PENDING,
        "candidate": target["url"],
        "target": dict(target),
        "reason": reason[:300],
        "updatedAt": timestamp(now),
    }


def started(target: Mapping[str, Any], pod: str, now: datetime.datetime) -> dict[str, Any]:
    """`status.rollout` of a shadow just started on `pod`."""
    stamp = timestamp(now)
    return {
        "phase": "Shadow",
        "candidate": target["url"],
        "target": dict(target),
        "pod": pod,
        "reason": "",
        "startedAt": stamp,
        "updatedAt": stamp,
    }


def from_state(old: Mapping[str, Any], state: Mapping[str, Any], now: datetime.datetime) -> dict[str, Any]:
    """`status.rollout` from the netapp's `GET /rollout` answer `state`, the operator's fields of `old` kept.
    Bounded: the netapp's text is cut, its numbers taken only when they are numbers."""
    p95 = state.get("p95_ms") if isinstance(state.get("p95_ms"), Mapping) else {}
    current, candidate = _number(p95.get("current")), _number(p95.get("candidate"))
    new = {
        **{k: old[k] for k in ("candidate", "target", "pod", "startedAt") if k in old},
        "phase": PHASES.get(str(state.get("phase")), old.get("phase", PENDING)),
        "framesCompared": int(_number(state.get("frames_compared")) or 0),
        "errors": int(_number(state.get("errors")) or 0),
        "reason": str(state.get("reason") or "")[:300],
        "updatedAt": timestamp(now),
    }
    for name, wire in (("agreement", "agreement"), ("maskIoU", "mask_iou"), ("oks", "oks")):
        value = _number(state.get(wire))
        if value is not None:
            new[name] = _agreement(value)
    if current is not None and candidate is not None:
        new["p95Ms"] = {"current": round(current, 2), "candidate": round(candidate, 2)}
        if current > 0:
            new["p95Ratio"] = round(candidate / current, 3)
    if new["phase"] in FINISHED:
        new["finishedAt"] = old.get("finishedAt") or timestamp(now)
    return new


def as_netapp_state(rollout: Mapping[str, Any]) -> dict[str, Any]:
    """`status.rollout` back in the terms of the netapp's `GET /rollout` (what the middleware shows of a rollout,
    netapp_middleware.rollouts): its phase, candidate, agreement, frames and p95 under the netapp's names."""
    phase = rollout.get("phase")
    state: dict[str, Any] = {"phase": _NETAPP_PHASES.get(str(phase), str(phase or "pending").lower())}
    for shown, written in (("model", "candidate"), ("reason", "reason"), ("started_at", "startedAt")):
        if rollout.get(written) is not None:
            state[shown] = rollout[written]
    for shown, written in (("frames_compared", "framesCompared"), ("errors", "errors")):
        if isinstance(rollout.get(written), int):
            state[shown] = rollout[written]
    try:
        state["agreement"] = float(rollout["agreement"])  # written as a string of three decimals
    except (KeyError, TypeError, ValueError):
        pass
    if isinstance(rollout.get("p95Ms"), Mapping):
        state["p95_ms"] = dict(rollout["p95Ms"])
    return state


def _agreement(value: float) -> str:
    """Agreement as a string with three decimals: what `kubectl get` prints, and what a CRD keeps exactly."""
    return f"{value:.3f}"


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def condition(
    conditions: list[Mapping[str, Any]] | None, rollout: Mapping[str, Any], served: Mapping[str, Any] | None, now
) -> list[dict[str, Any]]:
    """The NetApp's conditions with ModelRollout set for `rollout`: True promoted, False rolled back (saying what
    is served instead), Unknown while it runs."""
    phase, candidate = rollout.get("phase"), rollout.get("candidate")
    if phase == "Promoted":
        message = f"{candidate} is promoted: new pods start with it"
    elif phase == "RolledBack":
        message = f"{candidate} is rolled back ({rollout.get('reason')}): the pods serve {model_key(served)}"
    else:
        message = rollout.get("reason") or f"{candidate} is tried beside {model_key(served)}"
    value = (phase == "Promoted") if phase in FINISHED else "Unknown"  # running: neither true nor false yet
    return set_condition(conditions, CONDITION, value, str(phase), message[:1024], now)


def announcement(rollout: Mapping[str, Any], served: Mapping[str, Any] | None) -> tuple[str, str, str] | None:
    """The Event (type, reason, one-line message) a finished rollout posts; None while it runs."""
    candidate, frames = rollout.get("candidate"), rollout.get("framesCompared", 0)
    if rollout.get("phase") == "Promoted":
        ratio = rollout.get("p95Ratio")
        speed = f", p95 x{ratio}" if ratio is not None else ""
        return (
            "Normal",
            EVENT_PROMOTED,
            f"{candidate} promoted after {frames} frames (agreement {rollout.get('agreement', '-')}{speed}): "
            "new pods start with it",
        )
    if rollout.get("phase") == "RolledBack":
        return (
            "Warning",
            EVENT_ROLLED_BACK,
            f"{candidate} rolled back: {rollout.get('reason') or 'no reason given'}; "
            f"the Deployment keeps {model_key(served)}",
        )
    return None


def same(old: Mapping[str, Any], new: Mapping[str, Any]) -> bool:
    """Whether writing `new` would tell nothing new (the time of the last look aside)."""
    return {k: v for k, v in old.items() if k != "updatedAt"} == {k: v for k, v in new.items() if k != "updatedAt"}
