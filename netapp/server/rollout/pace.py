"""How fast a shadow gathers its evidence, and what to tell when its budget starves it: most sampled frames
skipped over budget, the time to a verdict at this pace, and what would shorten it. Pure."""

from __future__ import annotations

from netapp.server.rollout.shadow import SKIP_BUDGET, ShadowStats
from netapp.server.settings import Policy, Shadowing

MIN_SKIPS = 5  # a few skips at the start say little


def verdict_in_s(stats: ShadowStats, policy: Policy, elapsed_s: float) -> float | None:
    """Seconds to the end of this phase at the pace of its compared frames so far (an early verdict may come
    sooner); None before the first frame compared."""
    if stats.phase_frames == 0 or elapsed_s <= 0:
        return None
    per_s = stats.phase_frames / elapsed_s
    return max(0.0, policy.promote_after - stats.phase_frames) / per_s


def budget_note(stats: ShadowStats, policy: Policy, shadowing: Shadowing, elapsed_s: float) -> str | None:
    """One line when the budget skipped more sampled frames than were compared (None otherwise): how many, the
    pace, the time to a verdict, and the flag (and the NetApp's field) that would shorten it."""
    skipped = stats.skipped[SKIP_BUDGET]
    if skipped < MIN_SKIPS or skipped <= stats.frames:
        return None
    remaining = verdict_in_s(stats, policy, elapsed_s)
    when = (
        f"a verdict in about {_duration(remaining)} at this pace unless the evidence decides sooner"
        if remaining is not None
        else "no verdict in sight at this pace"
    )
    return (
        f"the shadow budget ({shadowing.budget:g} of the current model's time) skipped {skipped} of "
        f"{skipped + stats.frames} sampled frames: {stats.phase_frames} of {policy.promote_after} compared in "
        f"{_duration(elapsed_s)}, {when}; a larger --shadow-budget (shadowBudget) decides sooner"
    )


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min"
