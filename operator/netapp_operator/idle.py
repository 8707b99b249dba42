"""Scale to zero (pure): `spec.scaling.idleToZero`, when a NetApp is idle, asleep or woken
(docs/scaling.md#idle-scale-to-zero-and-wake-without-an-error).

A NetApp whose pods have all been ready and served no robot (`netapp_robots_per_replica`, the gauge the autoscaler
reads in /metrics, summed over its pods) for `idleToZero` goes to sleep: the idle poller (netapp_operator.idle_poll)
writes `status.idle = {since, wake}`, `wake` being the NetApp's wake annotation as it was then. The reconcile then
renders its Deployment with zero replicas and writes `phase: Idle`; the NetApp, its Service and its URL stay.

Anyone wanting it again (the middleware, for a robot asking for the app) writes a new value into the annotation
`netapp.dev/wake`: the NetApp is asleep only while the annotation still says what it said when it went to sleep,
so waking compares no clocks (the middleware's and the operator's may differ). Woken, it is rendered with its
replicas again and `status.idle` is removed. A new wake also restarts the poller's quiet clock: a robot just handed
the URL has not connected yet.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from typing import Any

from netapp.protocol import METRIC_ROBOTS
from netapp_operator.constants import ANNOTATION_WAKE

IDLE_PHASE = "Idle"
_DURATION = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*(ms|s|m|h)?\s*$")
_UNIT_S = {"ms": 0.001, "s": 1.0, "m": 60.0, "h": 3600.0, None: 1.0}
MIN_IDLE_S = 1.0  # less would put a netapp to sleep between two robots' frames


@dataclasses.dataclass(frozen=True)
class Scaling:
    idle_to_zero: Any = None  # as written: "5m", "30s", "1h", or seconds

    @property
    def idle_to_zero_s(self) -> float | None:
        return duration_s(self.idle_to_zero)


def duration_s(value: Any) -> float | None:
    """A duration ("90s", "5m", "1.5h", "250ms", or a number of seconds) in seconds; None when unreadable."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return float(value)
    match = _DURATION.match(value) if isinstance(value, str) else None
    return None if match is None else float(match.group(1)) * _UNIT_S[match.group(2)]


def parse_scaling(raw: Any) -> Scaling | None:
    if not isinstance(raw, Mapping):
        return None
    return Scaling(idle_to_zero=raw.get("idleToZero"))


def scaling_problems(scaling: Scaling | None, autoscaled: bool) -> list[str]:
    if scaling is None or scaling.idle_to_zero is None:
        return []
    seconds = scaling.idle_to_zero_s
    if seconds is None or seconds < MIN_IDLE_S:
        return [
            f"spec.scaling.idleToZero must be a duration of at least 1s (30s, 5m, 1h), got {scaling.idle_to_zero!r}"
        ]
    if autoscaled:
        return ["spec.scaling.idleToZero and spec.autoscaling both set the replicas: give one"]
    return []


def idle_after_s(spec: Any) -> float | None:
    """How long the NetApp may serve no robot before it sleeps; None when it never does."""
    scaling = getattr(spec, "scaling", None)
    return None if scaling is None or spec.autoscaling is not None else scaling.idle_to_zero_s


def wake_value(netapp: Mapping[str, Any]) -> str:
    return str(((netapp.get("metadata") or {}).get("annotations") or {}).get(ANNOTATION_WAKE) or "")


def asleep(netapp: Mapping[str, Any]) -> bool:
    """Whether the NetApp sleeps: the poller put it to sleep and nobody woke it since."""
    idle = (netapp.get("status") or {}).get("idle")
    return isinstance(idle, Mapping) and str(idle.get("wake") or "") == wake_value(netapp)


def idle_status(netapp: Mapping[str, Any], since: str) -> dict[str, Any]:
    """The status patch that puts the NetApp to sleep (the reconcile then scales it to zero)."""
    return {"idle": {"since": since, "wake": wake_value(netapp)}}


def woken_status() -> dict[str, Any]:
    """The status patch that wakes a sleeping NetApp (its waker's: netapp_operator.waker); the reconcile then renders
    its replicas again. The middleware wakes it through the wake annotation instead (it writes no status)."""
    return {"idle": None}


def wanted_replicas(netapp: Mapping[str, Any], replicas: Any) -> Any:
    """The Deployment's replicas: none while asleep, else the spec's."""
    return 0 if asleep(netapp) else replicas


def robots_in(metrics_text: str) -> float | None:
    """The robots a netapp serves, from its /metrics (Prometheus text); None when the gauge is missing."""
    for line in metrics_text.splitlines():
        if line.startswith(METRIC_ROBOTS) and line[len(METRIC_ROBOTS) : len(METRIC_ROBOTS) + 1] in (" ", "{"):
            try:
                return float(line.rsplit(None, 1)[-1])
            except ValueError:
                return None
    return None


@dataclasses.dataclass
class QuietClock:
    """Since when one NetApp has served no robot with all its pods ready (monotonic seconds), reset by a robot, a
    pod not ready, or a new wake."""

    since: float | None = None
    wake: str = ""

    def observe(self, now: float, wake: str, all_ready: bool, robots: float | None) -> float:
        """How long it has been quiet, given one look at it (`robots` None: a pod did not say)."""
        if wake != self.wake or not all_ready or robots is None or robots > 0:
            self.wake = wake
            self.since = None
            return 0.0
        if self.since is None:
            self.since = now
        return now - self.since


def with_idle(netapp: Mapping[str, Any], new: dict[str, Any]) -> dict[str, Any]:
    """A placed NetApp's new status with its sleep in it: `phase: Idle` once asleep at zero replicas, `idle` kept
    while asleep and removed (None, in a merge patch) once woken."""
    if not asleep(netapp):
        if (netapp.get("status") or {}).get("idle") is not None:
            new["idle"] = None
        return new
    new["idle"] = dict((netapp.get("status") or {})["idle"])
    if new.get("phase") == "Pending":  # at zero replicas (status.readiness: ScaledToZero)
        new["phase"] = IDLE_PHASE
    return new


def replicas_stale(netapp: Mapping[str, Any], spec: Any, deployment: Mapping[str, Any] | None) -> bool:
    """Whether the NetApp's Deployment has other replicas than it should, asleep or awake (rendered again)."""
    if deployment is None or spec.autoscaling is not None or idle_after_s(spec) is None and not asleep(netapp):
        return False
    return (deployment.get("spec") or {}).get("replicas") != wanted_replicas(netapp, spec.replicas)
