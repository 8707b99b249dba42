"""Switchover that triggers itself: when to move a robot to another placement (pure; no I/O, no clock).

A robot reports what its client measured on its netapp (`Report`: p95 latency, its deadline, frames that missed
it, over a window). `decide` moves it when its latency has stayed over its budget for `sustain_s` (an over-budget
streak, with hysteresis: the streak ends only once p95 falls below `recover_ratio` of the budget), it has been on
its placement for at least `min_dwell_s` (no flapping), and another eligible placement would do better: one the
robot measured there recently at a p95 under budget and under `margin` of today's, or one it has not tried yet.
A placement it left for being slow is therefore not tried again until its measurement is older than `memory_s`.

How long the breach must last depends on what a move would cost (`sustain_for`): into a netapp already Ready there
(`warm`: a standby, a route's readied pool, another robot's shared netapp) the move starts nothing and, hedged on
the robot (the old netapp serves until the new one answers on time), loses nothing, so a wrong move costs one dwell
on a netapp already running: `warm_sustain_s` (0: the first report over budget, itself a p95 over its window). A
cold move starts a netapp and its model, so it waits `sustain_s`. The hysteresis and the dwell time hold either way.

A rising trend moves it sooner (`rising`): when the p95 of the last `trend_window_s` climbs (the slope of a
least-squares line through at least `trend_min_points` reports, `trend_min_t` standard errors from flat and rising
at least `trend_min_rise` of the budget over them), is already in the upper band (at or over `recover_ratio` of the
budget: the hysteresis band, so a trend far below the budget never moves anyone) and would cross the budget within
`trend_horizon_s`, the move need not wait for `sustain_s` over budget. The dwell time and "would do better" still
hold.

A cold move need not start its netapp only once it is decided (`Decision.prepare`): as soon as the robot is over
budget, or its trend would cross the budget within `prepare_horizon_s`, and a move would be due but for the sustain
window (the dwell time over, a placement that would do better, no netapp Ready there), the decision names that
placement, and the loop starts its netapp at once without moving anyone. Once it is Ready the move into it is a warm
one; a robot that recovers leaves it to be released like any unneeded warm netapp.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass

# Kubernetes Event reasons (CamelCase) and the deployment's `history` entries.
MOVED = "SwitchedOver"
STAY_NO_BETTER = "NoBetterPlacement"
STAY_DWELL = "Dwelling"
STAY_OK = "WithinBudget"
STAY_SUSTAIN = "OverBudget"
MOVE_FAILED = "SwitchoverFailed"


@dataclass(frozen=True)
class Report:
    """One window of a robot's measurements on one placement; `p95_ms` is None when no result came back."""

    at: float
    placement: str
    p95_ms: float | None
    deadline_ms: float
    missed: int = 0
    window_s: float = 1.0

    @property
    def over(self) -> bool:
        """Over budget: a p95 above the deadline, or nothing back at all while frames missed it."""
        if self.p95_ms is None:
            return self.missed > 0
        return self.p95_ms > self.deadline_ms


@dataclass(frozen=True)
class SwitchPolicy:
    sustain_s: float = 2.0  # how long latency must stay over budget before a move that starts a netapp
    warm_sustain_s: float = 0.0  # ... before a move into a netapp already Ready (0: the first report over budget)
    recover_ratio: float = 0.8  # hysteresis: an over-budget streak ends only under this share of the budget
    min_dwell_s: float = 20.0  # no move sooner than this after arriving on a placement
    margin: float = 0.8  # a measured placement is better only under this share of the current p95
    memory_s: float = 300.0  # how long a placement's last measurement is trusted
    trend_window_s: float = 3.0  # the reports a latency trend is fitted over
    trend_horizon_s: float = 2.0  # move once the trend crosses the budget within this (0: no trend trigger)
    trend_min_points: int = 4  # fewer reports in the window make no trend
    trend_min_rise: float = 0.1  # a trend must rise this share of the budget over its window
    trend_min_t: float = 3.0  # and stand out of the jitter: its slope at least this many standard errors
    prepare: bool = True  # start a cold target's netapp at the first sign a move will be needed (`Decision.prepare`)
    prepare_horizon_s: float = 10.0  # ... a trend crossing the budget within this is such a sign

    def __post_init__(self) -> None:
        if not (0 < self.recover_ratio <= 1 and 0 < self.margin <= 1):
            raise ValueError("recover_ratio and margin must be in (0, 1]")
        if (
            min(
                self.sustain_s,
                self.warm_sustain_s,
                self.min_dwell_s,
                self.memory_s,
                self.trend_window_s,
                self.trend_horizon_s,
                self.prepare_horizon_s,
            )
            < 0
        ):
            raise ValueError("sustain_s, min_dwell_s, memory_s and the trend's window and horizon must not be negative")
        if self.trend_min_points < 2:
            raise ValueError("a trend needs at least 2 points")


@dataclass(frozen=True)
class Decision:
    move_to: str | None
    reason: str
    message: str
    prepare: str | None = None  # start a netapp there now (no move yet): the robot will likely need it (see module)


def sustain_for(policy: SwitchPolicy, warm: bool) -> float:
    """How long a breach must last before a move, by what the move costs (see the module): less into a warm netapp,
    never more than a cold move waits."""
    return min(policy.warm_sustain_s, policy.sustain_s) if warm else policy.sustain_s


def over_since(reports: Sequence[Report], policy: SwitchPolicy) -> float | None:
    """When the current over-budget streak began (reports oldest first); None when latency is within budget."""
    start: float | None = None
    for report in reports:
        if report.over:
            start = report.at if start is None else start
        elif report.p95_ms is not None and report.p95_ms < report.deadline_ms * policy.recover_ratio:
            start = None
        # Between recover_ratio x budget and the budget: neither starts nor ends a streak.
    return start


def slope(points: Sequence[tuple[float, float]]) -> tuple[float, float] | None:
    """The least-squares slope of (t, y) points (y per unit of t) and its t-statistic (the slope over its standard
    error: how far from noise it is; infinite for points on a line); None for fewer than 3 points or one instant."""
    n = len(points)
    if n < 3:
        return None
    mean_t = sum(t for t, _ in points) / n
    mean_y = sum(y for _, y in points) / n
    spread = sum((t - mean_t) ** 2 for t, _ in points)
    if spread <= 0:
        return None
    per = sum((t - mean_t) * (y - mean_y) for t, y in points) / spread
    residual = sum((y - mean_y - per * (t - mean_t)) ** 2 for t, y in points) / (n - 2)
    error = math.sqrt(residual / spread)
    return per, (math.inf if per > 0 else -math.inf if per < 0 else 0.0) if error == 0 else per / error


def trend(reports: Sequence[Report], now: float, policy: SwitchPolicy) -> tuple[float, float] | None:
    """The latency trend as (ms per s, seconds until it crosses the budget) when it is a real rise in the upper band
    (see the module), else None; the horizon is the caller's."""
    if not reports or reports[-1].p95_ms is None:
        return None
    latest = reports[-1]
    window = [(r.at, r.p95_ms) for r in reports if r.p95_ms is not None and now - r.at <= policy.trend_window_s]
    fit = slope(window) if len(window) >= policy.trend_min_points else None
    if fit is None or latest.p95_ms < latest.deadline_ms * policy.recover_ratio:
        return None
    per_s, significance = fit
    if per_s <= 0 or significance < policy.trend_min_t:
        return None  # jitter around a level, however close to the budget
    if per_s * (window[-1][0] - window[0][0]) < policy.trend_min_rise * latest.deadline_ms:
        return None  # a real rise, but a negligible one
    return per_s, max(0.0, (latest.deadline_ms - latest.p95_ms) / per_s)


def rising(reports: Sequence[Report], now: float, policy: SwitchPolicy) -> str | None:
    """Why the latency trend calls for a move now (see the module), or None when it does not."""
    fit = trend(reports, now, policy) if policy.trend_horizon_s > 0 else None
    if fit is None or fit[1] > policy.trend_horizon_s:
        return None
    per_s, crossing_s = fit
    budget = reports[-1].deadline_ms
    return f"rising {per_s:.0f} ms/s toward the {budget:.0f} ms budget (over it in {crossing_s:.1f} s)"


def decide(
    now: float,
    placement: str,
    arrived_at: float,
    reports: Sequence[Report],
    measured: Mapping[str, Report],
    eligible: Sequence[str],
    policy: SwitchPolicy,
    warm: Collection[str] = (),
) -> Decision:
    """Whether to move a robot now on `placement` (since `arrived_at`) and where.

    `reports`: its reports on `placement` since it arrived, oldest first; `measured`: its latest report on each
    other placement it has been on; `eligible`: the placements it may be moved to, in order of preference; `warm`:
    those where a netapp of its app is Ready now (a move there starts nothing).
    """
    start = over_since(reports, policy)
    why_rising = rising(reports, now, policy)
    latest = reports[-1] if reports else None
    if start is None and why_rising is None:
        ahead = trend(reports, now, policy) if policy.prepare else None
        if latest is None or ahead is None or ahead[1] > policy.prepare_horizon_s:
            return Decision(None, STAY_OK, f"latency on {placement} within budget")
        target = better_placement(now, placement, latest, measured, eligible, policy)
        cold = cold_target(target, warm, now - arrived_at >= policy.min_dwell_s)
        why = f"rising {ahead[0]:.0f} ms/s, over the budget in {ahead[1]:.1f} s"
        return Decision(None, STAY_OK, f"latency on {placement} within budget, {why}", cold)
    assert latest is not None  # a streak or a trend needs reports
    target = better_placement(now, placement, latest, measured, eligible, policy)
    sustain = sustain_for(policy, target is not None and target[0] in warm)
    p95 = "no result" if latest.p95_ms is None else f"p95 {latest.p95_ms:.0f} ms"
    if start is None or (now - start < sustain and why_rising is not None):
        over = f"{p95} on {placement}, {why_rising}"
    else:
        over = f"{p95} over the {latest.deadline_ms:.0f} ms budget on {placement} for {now - start:.1f} s"
        if now - start < sustain:
            cold = cold_target(target, warm, policy.prepare and now - arrived_at >= policy.min_dwell_s)
            return Decision(None, STAY_SUSTAIN, f"{over} (a move needs {sustain:.1f} s)", cold)
    if now - arrived_at < policy.min_dwell_s:
        return Decision(None, STAY_DWELL, f"{over}; on {placement} for less than {policy.min_dwell_s:.0f} s")
    if target is None:
        return Decision(None, STAY_NO_BETTER, f"{over}; no eligible placement would do better")
    name, why = target
    if name in warm:
        why = f"{why}; a netapp is Ready there"
    return Decision(name, MOVED, f"{over}; moving to {name} ({why})")


def cold_target(target: tuple[str, str] | None, warm: Collection[str], may_move: bool) -> str | None:
    """The placement to start a netapp on ahead of a move (`Decision.prepare`): the target, when the robot may move
    and nothing is Ready there."""
    return target[0] if target is not None and may_move and target[0] not in warm else None


def better_placement(
    now: float,
    placement: str,
    latest: Report,
    measured: Mapping[str, Report],
    eligible: Sequence[str],
    policy: SwitchPolicy,
) -> tuple[str, str] | None:
    """The placement that would do better than `placement` and why: the best measured one, else the first untried
    in order of preference; None when none would."""
    current = float("inf") if latest.p95_ms is None else latest.p95_ms
    better: list[tuple[float, int, str, str]] = []
    for rank, candidate in enumerate(eligible):
        if candidate == placement:
            continue
        last = measured.get(candidate)
        if last is None or now - last.at > policy.memory_s:
            better.append((float("inf"), rank, candidate, "not measured recently"))
        elif last.p95_ms is not None and last.p95_ms < min(last.deadline_ms, current * policy.margin):
            better.append((last.p95_ms, rank, candidate, f"p95 {last.p95_ms:.0f} ms there {now - last.at:.0f} s ago"))
    if not better:
        return None
    _, _, name, why = min(better)
    return name, why
