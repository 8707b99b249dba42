"""A rollout's gauges and counters in the netapp's /metrics (docs/rollouts.md#metrics)."""

from __future__ import annotations

import math
from typing import Protocol

from prometheus_client import CollectorRegistry, Counter, Gauge

from netapp.server.rollout.shadow import ShadowStats
from netapp.server.rollout.verdict import PHASES


class Watched(Protocol):
    """What the gauges read (a `Rollout`)."""

    phase: str
    stats: ShadowStats


class RolloutMetrics:
    def __init__(self, registry: CollectorRegistry) -> None:
        r = registry
        self.phase = Gauge(
            "netapp_rollout_phase", "1 for the rollout's phase now, 0 for the others", ["phase"], registry=r
        )
        self.compared = Gauge(
            "netapp_rollout_frames_compared", "Frames the candidate answered and was compared on", registry=r
        )
        self.agreement = Gauge(
            "netapp_rollout_agreement", "The candidate's agreement (F1) over the judging window", registry=r
        )
        self.p95 = Gauge(
            "netapp_rollout_p95_seconds", "p95 time of a frame over the judging window", ["model"], registry=r
        )
        self.errors = Gauge("netapp_rollout_candidate_errors", "Frames the candidate failed on", registry=r)
        self.skipped = Gauge(
            "netapp_rollout_frames_skipped", "Sampled frames the candidate did not run", ["reason"], registry=r
        )
        self.verdicts = Counter("netapp_rollout_verdicts", "Rollouts concluded, by verdict", ["verdict"], registry=r)
        for verdict in ("promoted", "rolled_back"):
            self.verdicts.labels(verdict=verdict)  # present at 0 from the start
        self.refused = Counter(
            "netapp_rollout_requests_refused", "POST /rollout requests refused, by reason", ["reason"], registry=r
        )

    def watch(self, rollout: Watched) -> None:
        """Gauges read from `rollout` at each scrape."""
        for phase in PHASES:
            self.phase.labels(phase=phase).set_function(lambda p=phase: float(rollout.phase == p))
        self.compared.set_function(lambda: rollout.stats.frames)
        self.agreement.set_function(lambda: rollout.stats.evidence().agreement if rollout.stats.frames else math.nan)
        self.p95.labels(model="current").set_function(lambda: _or_nan(rollout.stats.evidence().p95_current_s))
        self.p95.labels(model="candidate").set_function(lambda: _or_nan(rollout.stats.evidence().p95_candidate_s))
        self.errors.set_function(lambda: rollout.stats.errors)
        for reason in ("budget", "busy"):
            self.skipped.labels(reason=reason).set_function(lambda r=reason: rollout.stats.skipped[r])

    def verdict(self, phase: str) -> None:
        self.verdicts.labels(verdict=phase).inc()


def _or_nan(value: float | None) -> float:
    return math.nan if value is None else value
