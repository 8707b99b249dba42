"""What a rollout's evidence says: keep watching, go on to the canary, promote, or roll back and why. Pure."""

from __future__ import annotations

import math
import zlib
from collections.abc import Sequence
from dataclasses import dataclass

SHADOW, CANARY, PROMOTED, ROLLED_BACK = "shadow", "canary", "promoted", "rolled_back"
PHASES = (SHADOW, CANARY, PROMOTED, ROLLED_BACK)
FINAL = (PROMOTED, ROLLED_BACK)


@dataclass(frozen=True)
class Policy:
    """When a candidate is promoted or rolled back (`netapp serve --candidate`'s flags)."""

    promote_after: int = 200  # frames compared, each phase, before the next one
    min_agreement: float = 0.95  # F1 of matched boxes (or top-1 agreement) over the window
    max_slowdown: float = 1.5  # candidate p95 / current p95
    window: int = 50  # the latest frames compared that agreement and p95 are judged over
    max_errors: int = 0  # candidate failures tolerated
    canary_share: float = 0.0  # share of robots given the candidate's results after the shadow; 0: no canary

    def problem(self) -> str | None:
        """What is wrong with these values, in one line; None when they are usable."""
        if self.promote_after < 1:
            return "promote_after must be 1 or more frames"
        if not 0.0 <= self.min_agreement <= 1.0:
            return "min_agreement must be between 0 and 1"
        if not (math.isfinite(self.max_slowdown) and self.max_slowdown >= 1.0):
            return "max_slowdown must be 1 or more (the candidate's p95 over the current model's)"
        if self.window < 1:
            return "window must be 1 or more frames"
        if self.max_errors < 0:
            return "max_errors must be 0 or more"
        if not 0.0 <= self.canary_share < 1.0:
            return "canary_share must be at least 0 and below 1 (0: no canary)"
        return None

    @property
    def judged_after(self) -> int:
        """Frames compared before agreement and speed are judged at all (a few frames say little)."""
        return min(self.window, self.promote_after)


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
