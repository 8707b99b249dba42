"""What a rollout's evidence says: keep watching, go on to the canary, promote, or roll back and why. Pure."""

from __future__ import annotations

import math
import statistics
import zlib
from collections.abc import Sequence
from dataclasses import dataclass

from netapp.server.settings import Policy

SHADOW, CANARY, PROMOTED, ROLLED_BACK = "shadow", "canary", "promoted", "rolled_back"
PHASES = (SHADOW, CANARY, PROMOTED, ROLLED_BACK)
FINAL = (PROMOTED, ROLLED_BACK)
# The chance that an early verdict is wrong, over every look at the evidence together (the n-th look may err with
# ERROR_RATE / (n (n + 1)), and these sum to ERROR_RATE): the test is sequential, frame by frame, yet never "peeks".
ERROR_RATE = 0.05


@dataclass(frozen=True)
class Evidence:
    """What the comparison has seen so far."""

    phase_frames: int  # frames compared in the current phase
    window_frames: int  # frames in the judging window (at most Policy.window)
    agreement: float  # F1 over the window (1.0 with no frame)
    p95_current_s: float | None
    p95_candidate_s: float | None
    errors: int = 0
    last_error: str | None = None
    frame_agreements: tuple[float, ...] = ()  # each frame's agreement (F1) in this phase, for the early verdict
    slowdowns: tuple[float, ...] = ()  # each frame's candidate time over the current model's, timed alike


@dataclass(frozen=True)
class Verdict:
    phase: str
    reason: str | None = None


def judge(phase: str, evidence: Evidence, policy: Policy) -> Verdict:
    """The rollout's next phase given `evidence`: rolled back on errors; as soon as the evidence is decisive
    (`decisive_rollback`); on agreement below the floor, or on a candidate more than `max_slowdown` times slower
    on the median frame timed alike (once `judged_after` frames were compared); after `promote_after` frames of a
    phase, the next phase (the canary, if any, then promoted)."""
    if phase in FINAL:
        return Verdict(phase)
    if evidence.errors > policy.max_errors:
        return Verdict(ROLLED_BACK, f"the candidate failed on {evidence.errors} frame(s): {evidence.last_error}")
    early = decisive_rollback(evidence, policy)
    if early is not None:
        return Verdict(ROLLED_BACK, early)
    if evidence.window_frames >= policy.judged_after:
        if evidence.agreement < policy.min_agreement:
            return Verdict(
                ROLLED_BACK,
                f"agreement (F1) {evidence.agreement:.3f} over the last {evidence.window_frames} frames is below "
                f"{policy.min_agreement}",
            )
        ratios = evidence.slowdowns[-policy.window :]
        if ratios and statistics.median(ratios) > policy.max_slowdown:
            return Verdict(ROLLED_BACK, f"{_slower(evidence, ratios)}; at most {policy.max_slowdown}x is allowed")
    if evidence.phase_frames >= policy.promote_after:
        if phase == SHADOW and policy.canary_share > 0:
            return Verdict(CANARY, f"the shadow agreed on {evidence.phase_frames} frames")
        return Verdict(PROMOTED, f"agreed on {evidence.phase_frames} frames of the {phase}")
    return Verdict(phase)


def decisive_rollback(evidence: Evidence, policy: Policy) -> str | None:
    """Why the candidate fails beyond doubt already, or None: its agreement's upper confidence bound is below
    `min_agreement` (agreement 0.000 on five frames is enough), or it is slower than `max_slowdown` on so many of
    the frames timed alike that a median ratio within it is implausible (a sign test; 12 of 12 frames is enough).
    Each at `ERROR_RATE` over all the looks of the rollout."""
    values = evidence.frame_agreements
    if values and (upper := agreement_upper_bound(values)) < policy.min_agreement:
        return (
            f"agreement (F1) {statistics.fmean(values):.3f} over {len(values)} frames is below "
            f"{policy.min_agreement} beyond doubt (at most {upper:.3f} at {1 - ERROR_RATE:.0%} confidence)"
        )
    ratios = evidence.slowdowns
    slower = sum(r > policy.max_slowdown for r in ratios)
    if ratios and sign_test(slower, len(ratios)) <= _look_rate(len(ratios)):
        return f"{_slower(evidence, ratios)}, over {policy.max_slowdown}x on {slower} of them: beyond doubt"
    return None


def _slower(evidence: Evidence, ratios: Sequence[float]) -> str:
    """How much slower the candidate is: the median of its frames' time over the current model's, each pair timed
    alike (robust to a busy machine's spikes, which a p95 of 20 frames is not), and the two p95s."""
    text = f"the candidate is {statistics.median(ratios):.1f}x slower on the median of {len(ratios)} frames timed alike"
    current, candidate = evidence.p95_current_s, evidence.p95_candidate_s
    if current and candidate:
        text += f" (at p95 {candidate * 1000:.1f} ms against {current * 1000:.1f} ms)"
    return text


def agreement_upper_bound(values: Sequence[float]) -> float:
    """An upper bound of the mean of `values` (each in [0, 1]) that holds with probability 1 - ERROR_RATE over
    every look (Hoeffding's inequality at the look's share of the error rate)."""
    n = len(values)
    return statistics.fmean(values) + math.sqrt(math.log(2 / _look_rate(n)) / (2 * n))


def sign_test(successes: int, n: int) -> float:
    """P(at least `successes` of `n` fair coin flips): how likely so many slower frames are from a candidate that
    is within the allowed slowdown on half of them or more."""
    return sum(math.comb(n, k) for k in range(successes, n + 1)) / 2**n


def _look_rate(n: int) -> float:
    return ERROR_RATE / (n * (n + 1))


def p95(values: Sequence[float]) -> float | None:
    """The 95th percentile (nearest rank) of `values`; None when empty."""
    if not values:
        return None
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, math.ceil(0.95 * len(ordered)) - 1)]


def in_canary(robot: str, share: float) -> bool:
    """Whether a robot (its id, else its session's) is among the `share` that get the candidate's results in the
    canary: stable (a hash of the id, not a random draw per frame)."""
    return zlib.crc32(robot.encode()) / 2**32 < share
