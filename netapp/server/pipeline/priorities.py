"""Priority classes (docs/scaling.md#priorities): which class a robot may have, and which class's turn it is.

A robot's class comes from its INIT data or /register args (`netapp.protocol.PRIORITY_FIELD`); it may be at most the
class its token grants (`netapp.server.access.granted_class`), so a robot can lower itself, never raise itself above
what whoever gave it its token chose.

Between classes the turns go by stride scheduling: each class has a weight and a pass, the inference time it was
given over its weight; the waiting class with the lowest pass goes next (the higher class on a tie), and a class that
had nothing waiting starts again level with the others rather than with the time it did not use. So a class that
needs less than its share is served at once, a higher one first, and when every class has frames waiting each gets
its weight's share of the netapp's time: the lowest class keeps a floor, never starved. Within a class the turns
are weighed by cost (`netapp.server.pipeline.scheduling`).
"""

from __future__ import annotations

import math
from typing import Any

from netapp.protocol import (
    BAD_PRIORITY_REASON,
    PRIORITY_CLASSES,
    PRIORITY_FIELD,
    PRIORITY_NOT_ALLOWED_REASON,
    parse_priority,
)
from netapp.server.errors import RequestRefused
from netapp.server.settings import DEFAULT_WEIGHTS

HIGHEST = len(PRIORITY_CLASSES) - 1


def robot_priority(args: dict[str, Any], granted: int) -> int:
    """The class a robot asks for in `args` (none: `granted`); RequestRefused 422 for a class there is not, 403 for
    one above `granted`."""
    claimed = args.get(PRIORITY_FIELD)
    if claimed is None:
        return granted
    try:
        priority = parse_priority(claimed)
    except ValueError as exc:
        raise RequestRefused(BAD_PRIORITY_REASON, str(exc), 422) from exc
    if priority > granted:
        raise RequestRefused(
            PRIORITY_NOT_ALLOWED_REASON,
            f"this robot may claim {PRIORITY_FIELD} {PRIORITY_CLASSES[granted]} at most, not "
            f"{PRIORITY_CLASSES[priority]}: a higher class needs that class's token (docs/scaling.md#priorities)",
            403,
            granted=PRIORITY_CLASSES[granted],
        )
    return priority


def parse_weights(text: str) -> tuple[float, ...]:
    """`low=1,normal=2,high=4` -> each class's weight, in class order; a class left out keeps its default weight.
    ValueError, one line saying what to write, for anything else."""
    weights = list(DEFAULT_WEIGHTS)
    example = ",".join(f"{c}={w:g}" for c, w in zip(PRIORITY_CLASSES, DEFAULT_WEIGHTS, strict=True))
    for item in (part.strip() for part in text.split(",")):
        name, sep, number = item.partition("=")
        try:
            index = PRIORITY_CLASSES.index(name.strip().lower()) if sep else -1
            weight = float(number)
        except ValueError:
            index, weight = -1, math.nan
        if index < 0 or not (math.isfinite(weight) and weight > 0):
            raise ValueError(
                f"--priority-weights takes CLASS=WEIGHT pairs, classes {', '.join(PRIORITY_CLASSES)} and weights "
                f"above 0 (e.g. {example}), got {item[:40]!r}"
            )
        weights[index] = weight
    return tuple(weights)


def floor_shares(weights: tuple[float, ...]) -> list[float]:
    """Each class's share of the netapp's time when every class has frames waiting (its floor)."""
    return [w / sum(weights) for w in weights]


USE_WINDOW_S = 1.0  # each class's use of the inference time is averaged over about this long


class ClassTurns:
    """Stride scheduling between the classes: `pick` the class whose turn it is among those with frames waiting,
    `charge` it the inference time its turn costs, `wake` a class that had nothing waiting. It also keeps how much
    of the netapp's time each class has been using lately (`use`), for the next-turn estimate."""

    def __init__(self, weights: tuple[float, ...]) -> None:
        if len(weights) != len(PRIORITY_CLASSES) or min(weights) <= 0:
            raise ValueError(f"one positive weight per class {PRIORITY_CLASSES}, got {weights}")
        self.weights = weights
        self.passes = [0.0] * len(weights)
        self._now = 0.0  # the pass of the class that last had a turn: where a waking class starts
        self._use = [0.0] * len(weights)  # seconds of inference time per second, decaying over USE_WINDOW_S
        self._use_at = 0.0

    def wake(self, priority: int) -> None:
        """`priority` has frames waiting again: it starts level with the others (it cannot bank unused time)."""
        self.passes[priority] = max(self.passes[priority], self._now)

    def pick(self, waiting: list[int]) -> int:
        """The class whose turn it is among `waiting` (not empty): the lowest pass, the higher class on a tie."""
        return min(waiting, key=lambda c: (self.passes[c], -c))

    def charge(self, priority: int, cost_s: float, now_s: float = 0.0) -> None:
        """`priority` had a turn costing `cost_s` of inference time, at `now_s` (monotonic seconds)."""
        self._now = self.passes[priority]
        self.passes[priority] += cost_s / self.weights[priority]
        self.use(now_s)
        self._use[priority] += cost_s / USE_WINDOW_S

    def use(self, now_s: float) -> list[float]:
        """Each class's recent use of the netapp's time, seconds per second (decayed to `now_s`)."""
        if now_s > self._use_at:
            decay = math.exp(-(now_s - self._use_at) / USE_WINDOW_S)
            self._use = [u * decay for u in self._use]
            self._use_at = now_s
        return list(self._use)
