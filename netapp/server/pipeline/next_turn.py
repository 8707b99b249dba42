"""When the netapp will take a session's next frame (pure): the next-turn hint each result carries, so a paced robot
sends its next frame to arrive just before its turn rather than to wait in the queue
(`docs/client.md#the-next-turn-hint`).

A busy netapp gives out its inference time in turns (`netapp.server.pipeline.scheduling`): each session of a class one
turn a round, costing its measured `cost_s`, and each class its weight's share of the time
(`netapp.server.pipeline.priorities`). A session's turns therefore come a round of its class apart, that round stretched
by its class's share: `sum(costs of its class) / share`, where the share is its weight's, or what the other classes
leave when they use less (a high robot that needs a fifth of the time leaves the rest to the others). Its next turn is
that long after its last one started. The costs are inference-thread time per frame, already shared out between lanes,
so at full load they add up to one second a second; below full load a turn comes as soon as a frame arrives, and the
estimate (at most one round of the robots streaming now) errs early, never late: a frame that arrives early waits a
little, one that arrives late goes to the back of the line.
"""

from __future__ import annotations

from collections.abc import Iterable

MAX_NEXT_TURN_S = 1.0  # never tell a robot to hold a frame longer than this, whatever the sums say
STREAMING_S = 1.0  # a session that sent a frame this recently is streaming now: it takes turns


def next_turn_in_s(
    priority: int,
    cost_s: float,
    since_turn_s: float,
    others: Iterable[tuple[int, float]],
    weights: tuple[float, ...],
    use: list[float] | None = None,
) -> float:
    """Seconds from now until a session's next turn: its class `priority`, its `cost_s`, how long ago its last turn
    started, and the (class, cost) of the other sessions streaming now (a cost of 0, not yet measured, counts as
    the session's own). `use`: each class's recent use of the netapp's time (seconds per second): a class gets
    whatever the others leave, and at least its weight's share (stride scheduling gives it that when it waits)."""
    sessions = [(priority, cost_s), *((c, cost or cost_s) for c, cost in others)]
    classes = {c for c, _ in sessions}
    share = weights[priority] / sum(weights[c] for c in classes)
    if use is not None:
        left = 1.0 - sum(use[c] for c in classes if c != priority)
        share = min(1.0, max(share, left))
    class_round_s = sum(cost for c, cost in sessions if c == priority)
    return min(MAX_NEXT_TURN_S, max(0.0, class_round_s / share - since_turn_s))
