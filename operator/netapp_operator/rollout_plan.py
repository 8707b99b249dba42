"""When to start, follow or leave a NetApp's model rollout (pure, docs/rollouts.md): the one planner that both
drivers ask on each tick, the operator's (`rollout_poll.RolloutPoller`: a pod of the NetApp's Deployment) and the
middleware's (`netapp_middleware/model_rollouts.ModelRollouts`: the local backend's process). Each driver keeps
only its I/O: it says what the spec wants, what the netapp serves, whether it is ready and what it last saw of the
rollout (`Attempt`), does what `next_step` says, and announces what `announce_now` says.

The rules, the same for both: a rollout under way is followed to its verdict, whatever the spec says meanwhile; a
model is tried once whatever its verdict (after a rollback the netapp serves the model it had until the spec names
another); a request the netapp refused is tried again only once it changes; a verdict is announced once.
"""

from __future__ import annotations

import dataclasses
from typing import Any

START, FOLLOW, LEAVE = "start", "follow", "leave"  # what a driver does next

# Where a rollout stands, whoever drives it
PENDING = "pending"  # asked for, not under way: no ready netapp yet, or its netapp did not answer (tried again)
RUNNING = "running"  # a shadow or canary on its netapp: ask it how it goes
PROMOTED, ROLLED_BACK = "promoted", "rolled_back"  # the netapp's verdicts (GET /rollout's `phase`)
REFUSED = "refused"  # the netapp would not start it as asked: tried again when the request changes
VERDICTS = (PROMOTED, ROLLED_BACK, REFUSED)

# The netapp's GET /rollout phases and the operator's `status.rollout.phase` -> the stage
_STAGES = {
    "shadow": RUNNING,
    "canary": RUNNING,
    "Shadow": RUNNING,
    "Canary": RUNNING,
    "promoted": PROMOTED,
    "Promoted": PROMOTED,
    "rolled_back": ROLLED_BACK,
    "RolledBack": ROLLED_BACK,
    "refused": REFUSED,
}


def stage_of(phase: Any) -> str:
    """A rollout's stage from a phase as the netapp (`shadow`, ...) or the NetApp's status (`Shadow`, ...) says it;
    PENDING for anything else."""
    return _STAGES.get(str(phase), PENDING)


@dataclasses.dataclass(frozen=True)
class Attempt:
    """What a driver last saw of a NetApp's rollout."""

    target: Any  # the model it tries, as the driver names models (compared with `wanted` and `serving`)
    stage: str  # PENDING, RUNNING or one of VERDICTS
    on: str | None = None  # where it runs once started (a pod's name, a process); None before
    request: Any = None  # what was asked (for REFUSED: what the netapp refused)

    @property
    def under_way(self) -> bool:
        return self.stage == RUNNING and bool(self.on)


def next_step(wanted: Any, serving: Any, ready: bool, last: Attempt | None, request: Any = None) -> str:
    """What a driver does next on one NetApp: FOLLOW the rollout under way, START one of `wanted` (the model the
    spec asks for, None when none can be tried), or LEAVE it: nothing to try, nothing to compare it with (`serving`
    None: a model the spec did not name), the netapp not ready, the model served already, this model judged
    already, or `request` refused as it stands."""
    if last is not None and last.under_way:
        return FOLLOW
    if wanted is None or serving is None or not ready or wanted == serving:
        return LEAVE
    if last is None or last.target != wanted:
        return START
    if last.stage in (PROMOTED, ROLLED_BACK) or (last.stage == REFUSED and last.request == request):
        return LEAVE
    return START


def announce_now(before: str | None, after: str) -> bool:
    """Whether a rollout that was at stage `before` and is now at `after` has a verdict to announce (once)."""
    return after in VERDICTS and before not in VERDICTS
