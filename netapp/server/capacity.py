"""How many robots this netapp can serve, from what it measures: the estimator is pure (fed numbers, no clock, no
I/O), the pipeline feeds it, and /metrics, the 5G-ERA heartbeat and admission read it.

The model. Inference is the bottleneck: each lane's thread decodes (when no prepare pool does), prepares and runs a
batch, one batch at a time. A batch's busy time over the lanes busy beside it (they share the cores), per batch of
`b` frames, `t(b)` (a moving average per batch size), gives the throughput `b / t(b)`; the best batch size seen
is its capacity `C` in results per second. A robot streams at its own input rate (its camera rate, measured per
session on arrival); `demand` is the median robot's rate. Then:

- optimal limit: robots served at their full rate with `headroom` to spare, `floor(C * headroom / demand)`;
- hard limit: robots that each still get `hard_share` of their rate, `floor(C / (demand * hard_share))`. Past it a
  new robot is refused (503 + Retry-After on /register, a refused INIT on Socket.IO) rather than slowing everyone.

Round robin between robots (the pipeline's ready queue) shares `C` evenly, so each robot's share is `C / robots`
once robots exceed the optimal limit; with a newest-wins queue of one frame, latency grows by about one inference
per robot ahead in the round, which `hard_share` bounds too (at 0.5: a result at least every second frame period).
Until the first batch is measured, both limits are unknown (None) and only a static cap applies. The hard limit
refuses robots only where the deployment chose it (`Settings.admission`, `docs/scaling.md#admission`), and only once
the estimate is warm: `min_batches` batches seen, so a netapp's first seconds (a cold model, a start storm) refuse
nobody.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, field


def smoothed(old: float | None, new: float, alpha: float) -> float:
    """An exponential moving average: `old` moved `alpha` of the way to `new` (None: no value yet, `new` itself)."""
    return new if old is None else old + alpha * (new - old)


@dataclass(frozen=True)
class CapacityLimits:
    """What the estimator publishes (the 5G-ERA heartbeat's `optimalLimit` and `hardLimit`, and /metrics)."""

    capacity_fps: float | None  # results per second the inference thread can sustain
    demand_fps: float  # the median robot's input rate (or the default before any robot streams)
    optimal: int | None
    hard: int | None
    measured: bool  # both capacity and demand measured (not the default rate): only then is a robot refused


@dataclass
class CapacityEstimator:
    """Fed batch timings and robot input rates; answers the limits. Pure: the caller supplies every number."""

    default_robot_fps: float = 10.0  # the input rate assumed until robots stream
    max_robot_fps: float = 30.0  # a robot sending faster (a closed loop, a benchmark) counts as a camera at this rate
    headroom: float = 0.9  # the optimal limit keeps this fraction of capacity in use, the rest spare
    hard_share: float = 0.5  # the hard limit: each robot still gets this share of its input rate (0: no hard limit)
    alpha: float = 0.1  # weight of a new batch timing in its moving average
    min_batches: int = 50  # batches observed before the estimate may refuse anyone (a cold netapp's are slow)
    batches: int = 0  # batches observed so far
    _busy_s: dict[int, float] = field(default_factory=dict)  # batch size -> moving average of busy seconds

    def observe_batch(self, size: int, busy_s: float) -> None:
        """One batch of `size` frames kept the inference thread busy `busy_s` seconds (decode through results)."""
        if size < 1 or not math.isfinite(busy_s) or busy_s <= 0:
            return
        self.batches += 1
        self._busy_s[size] = smoothed(self._busy_s.get(size), busy_s, self.alpha)

    def capacity_fps(self) -> float | None:
        """Results per second at the best batch size measured; None before any batch."""
        if not self._busy_s:
            return None
        return max(size / busy for size, busy in list(self._busy_s.items()))  # fed from the inference thread

    def demand_fps(self, robot_rates: list[float]) -> float:
        """The median robot's input rate (robots with a measured rate), else the default."""
        rates = [min(r, self.max_robot_fps) for r in robot_rates if r > 0 and math.isfinite(r)]
        return statistics.median(rates) if rates else self.default_robot_fps

    def limits(self, robot_rates: list[float]) -> CapacityLimits:
        capacity = self.capacity_fps()
        demand = self.demand_fps(robot_rates)
        if capacity is None:
            return CapacityLimits(None, demand, None, None, measured=False)
        optimal = max(1, math.floor(capacity * self.headroom / demand))
        hard = max(optimal, math.floor(capacity / (demand * self.hard_share))) if self.hard_share > 0 else None
        return CapacityLimits(capacity, demand, optimal, hard, measured=any(r > 0 for r in robot_rates))

    def admission_limit(self, robot_rates: list[float]) -> int | None:
        """Sessions past which a new robot is refused: the hard limit, once capacity and demand are measured and
        the estimate is warm (`min_batches`)."""
        limits = self.limits(robot_rates)
        return limits.hard if limits.measured and self.batches >= self.min_batches else None


@dataclass
class InputRate:
    """A robot's input rate from its frames' arrival times (a moving average of the interval between them)."""

    alpha: float = 0.1
    interval_s: float | None = None
    last_s: float | None = None

    def arrived(self, now_s: float) -> None:
        if self.last_s is not None:
            gap = now_s - self.last_s
            if gap > 0 and self.interval_s is None:
                self.interval_s = gap
            elif gap > 0:
                self.interval_s += self.alpha * (gap - self.interval_s)
        self.last_s = now_s

    def fps(self, now_s: float, stale_s: float = 5.0) -> float | None:
        """Frames per second, or None before two frames or once the robot has been silent `stale_s` seconds."""
        if self.interval_s is None or self.last_s is None or now_s - self.last_s > stale_s:
            return None
        return 1.0 / self.interval_s
