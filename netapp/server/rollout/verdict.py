"""What a rollout's evidence says: keep watching, go on to the canary, promote, or roll back and why. Pure."""

from __future__ import annotations

import math
import zlib
from collections.abc import Sequence
from dataclasses import dataclass

from netapp.server.settings import Policy

SHADOW, CANARY, PROMOTED, ROLLED_BACK = "shadow", "canary", "promoted", "rolled_back"
PHASES = (SHADOW, CANARY, PROMOTED, ROLLED_BACK)
FINAL = (PROMOTED, ROLLED_BACK)


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


@dataclass(frozen=True)
class Verdict:
    phase: str
    reason: str | None = None


def judge(phase: str, evidence: Evidence, policy: Policy) -> Verdict:
    """The rollout's next phase given `evidence`: rolled back on errors, on agreement below the floor, or on a
    candidate more than `max_slowdown` times slower at p95 (once `judged_after` frames were compared); after
    `promote_after` frames of a phase, the next phase (the canary, if any, then promoted)."""
    if phase in FINAL:
        return Verdict(phase)
    if evidence.errors > policy.max_errors:
        return Verdict(ROLLED_BACK, f"the candidate failed on {evidence.errors} frame(s): {evidence.last_error}")
    if evidence.window_frames >= policy.judged_after:
        if evidence.agreement < policy.min_agreement:
            return Verdict(
                ROLLED_BACK,
                f"agreement (F1) {evidence.agreement:.3f} over the last {evidence.window_frames} frames is below "
                f"{policy.min_agreement}",
            )
        current, candidate = evidence.p95_current_s, evidence.p95_candidate_s
        if current and candidate and candidate > policy.max_slowdown * current:
            return Verdict(
                ROLLED_BACK,
                f"the candidate is {candidate / current:.1f}x slower at p95 ({candidate * 1000:.1f} ms against "
                f"{current * 1000:.1f} ms); at most {policy.max_slowdown}x is allowed",
            )
    if evidence.phase_frames >= policy.promote_after:
        if phase == SHADOW and policy.canary_share > 0:
            return Verdict(CANARY, f"the shadow agreed on {evidence.phase_frames} frames")
        return Verdict(PROMOTED, f"agreed on {evidence.phase_frames} frames of the {phase}")
    return Verdict(phase)


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
