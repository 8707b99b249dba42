"""A NetApp's `spec.rollout` (or a new `spec.model`) as the request that starts a rollout on its running netapp:
`POST /rollout` (docs/rollouts.md); which model a spec asks for, the one line that tells a rollout's outcome, and
what is kept of a rollout whose netapp stopped before a verdict. Pure."""

from __future__ import annotations

from typing import Any

# One builder of the request, the operator's and this one's (netapp_operator.rollouts)
from netapp_operator.rollout_plan import PROMOTED, REFUSED, ROLLED_BACK, VERDICTS, stage_of
from netapp_operator.rollouts import EVENT_PROMOTED, EVENT_ROLLED_BACK, rollout_request

# A NetApp's model as the catalogue names it: (model or candidate, its sha256 or "").
ModelKey = tuple[str, str]

# Events (a log line on the local backend), one per rollout's outcome
EVENT_REFUSED = "RolloutRefused"
EVENT_STOPPED = "RolloutStopped"  # its netapp stopped (its robots left, it slept, it exited) before a verdict
# The middleware's phase for such a rollout: not the netapp's (whose own record went with its process)
STOPPED = "stopped"
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


def no_verdict(state: dict[str, Any]) -> str:
    """Why a rollout whose netapp stopped has no verdict, with what it had seen: `no verdict: stopped after 17 frames
    compared, agreement 0.000, slowdown 6.20x (p95 812.4 ms against 131.0 ms)`."""
    frames = state.get("frames_compared")
    if not isinstance(frames, int) or frames <= 0:
        return "no verdict: its netapp stopped before any frame was compared"
    seen = [f"stopped after {frames} frames compared"]
    agreement = state.get("agreement")
    if _number(agreement):
        seen.append(f"agreement {agreement:.3f}")
    p95 = state.get("p95_ms") if isinstance(state.get("p95_ms"), dict) else {}
    current, candidate = p95.get("current"), p95.get("candidate")
    if _number(current) and _number(candidate) and current > 0:
        seen.append(f"slowdown {candidate / current:.2f}x (p95 {candidate} ms against {current} ms)")
    return "no verdict: " + ", ".join(seen)


def final_record(shown: dict[str, Any], stopped_at: float) -> dict[str, Any]:
    """What the API keeps of a rollout (as `rollout_summary` shows it) once its netapp stopped at `stopped_at`: its
    verdict as it was, else phase `stopped` and `no_verdict`'s reason."""
    final = {**shown, "stopped_at": round(stopped_at, 3)}
    if stage_of(shown.get("phase")) not in VERDICTS:
        final.update(phase=STOPPED, reason=no_verdict(shown))
    return final


def stopped_event(app: str, shown: dict[str, Any]) -> tuple[str, str, str]:
    """The Event (type, reason, message) of a rollout `ended` without a verdict."""
    return "Warning", EVENT_STOPPED, f"{app}: rollout of {shown.get('model')}: {shown.get('reason')}"


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)
