"""Which frames the candidate sees, and within what budget; and what the comparison has seen (the evidence the
verdict reads). No I/O: the rollout feeds these from the inference path."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from netapp.models.matching import FrameAgreement, agreement
from netapp.server.rollout.verdict import Evidence, p95

SKIP_BUDGET, SKIP_BUSY = "budget", "busy"


@dataclass
class Sampler:
    """Every 1/`share`-th frame, evenly (a credit, not a random draw: the same frames for the same traffic), and
    only while the candidate's time stays within `budget` of the current model's inference time."""

    share: float
    budget: float
    _credit: float = 0.0
    current_busy_s: float = 0.0
    candidate_busy_s: float = 0.0

    def current_ran(self, seconds: float) -> None:
        self.current_busy_s += seconds

    def candidate_ran(self, seconds: float) -> None:
        self.candidate_busy_s += seconds

    def wants(self) -> bool:
        """Whether this frame is one of the sample."""
        self._credit += self.share
        if self._credit >= 1.0:
            self._credit -= 1.0
            return True
        return False

    def within_budget(self) -> bool:
        """Whether the candidate may run once more: its time so far is within `budget` of the current model's
        (the first run is always allowed, to measure it)."""
        return self.candidate_busy_s == 0.0 or self.candidate_busy_s <= self.budget * self.current_busy_s


@dataclass
class ShadowStats:
    """The comparisons of the latest `window` frames, the two models' times on them, and the counts since the
    rollout began."""

    window: int
    frames: int = 0
    phase_frames: int = 0
    errors: int = 0
    last_error: str | None = None
    skipped: dict[str, int] = field(default_factory=lambda: {SKIP_BUDGET: 0, SKIP_BUSY: 0})
    _agreements: deque[FrameAgreement] = field(default_factory=deque)
    _current_s: deque[float] = field(default_factory=deque)
    _candidate_s: deque[float] = field(default_factory=deque)

    def compared(self, result: FrameAgreement, current_s: float, candidate_s: float) -> None:
        self.frames += 1
        self.phase_frames += 1
        for values, value in (
            (self._agreements, result),
            (self._current_s, current_s),
            (self._candidate_s, candidate_s),
        ):
            values.append(value)
            if len(values) > self.window:
                values.popleft()

    def failed(self, error: str) -> None:
        self.errors += 1
        self.last_error = error

    def skip(self, reason: str) -> None:
        self.skipped[reason] += 1

    def next_phase(self) -> None:
        self.phase_frames = 0

    def evidence(self) -> Evidence:
        summary = agreement(list(self._agreements))
        return Evidence(
            phase_frames=self.phase_frames,
            window_frames=len(self._agreements),
            agreement=summary.f1,
            p95_current_s=p95(self._current_s),
            p95_candidate_s=p95(self._candidate_s),
            errors=self.errors,
            last_error=self.last_error,
        )

    def summary(self) -> dict[str, float | None]:
        """Agreement over the window: F1, and mean mask IoU and OKS of the matched pairs (None: none had any)."""
        summary = agreement(list(self._agreements))
        return {"f1": summary.f1, "mask_iou": summary.mask_iou, "oks": summary.oks}
