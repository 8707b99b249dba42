"""A rollout on a running netapp: the candidate is loaded beside the current model (a load that fails is a rollback
with the reason), runs on a sample of frames after their results have gone to their robots, within a budget, and the
verdict promotes it in place (between batches: no session dropped) or unloads it.

The candidate's work runs on a thread of its own, one frame at a time: a frame sampled while it is busy is skipped
and counted, so a slow candidate never queues frames, and the robots' results never wait for it."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict
from typing import Any

from netapp.models.matching import FrameAgreement
from netapp.sdk.processor import Processor
from netapp.server.errors import FrameRejected
from netapp.server.pipeline.frame import Frame
from netapp.server.pipeline.scheduling import Batch
from netapp.server.rollout.compare import compare_results
from netapp.server.rollout.metrics import RolloutMetrics
from netapp.server.rollout.shadow import SKIP_BUDGET, SKIP_BUSY, Sampler, ShadowStats
from netapp.server.rollout.verdict import CANARY, FINAL, PROMOTED, ROLLED_BACK, SHADOW, in_canary, judge
from netapp.server.sessions import Session
from netapp.server.settings import Policy, Shadowing

log = logging.getLogger(__name__)

NONE = "none"  # no rollout has been asked for

# (model, sha256) -> the candidate, loaded (it raises saying why it cannot be)
CandidateFactory = Callable[[str, "str | None"], Processor]


class RolloutRefused(Exception):
    """A rollout that cannot start now; the message says why and what to do."""


def same_preparation(current: Processor, candidate: Processor) -> bool:
    """Whether a frame prepared for `current` is one `candidate` takes as it is (the same pixels and
    family, and inputs of the same names, shapes and types, as two exports of one detector): then the candidate runs on
    the very same prepared input."""
    a, b = getattr(current, "card", None), getattr(candidate, "card", None)
    return (
        a is not None
        and b is not None
        and type(current) is type(candidate)
        and a.pixels == b.pixels
        and a.family == b.family
        and a.inputs == b.inputs  # names, shapes and element types: an fp16 export prepares its own
    )


class Rollout:
    """The pipeline's `InferenceHook` (netapp/server/pipeline/hooks.py) that judges a candidate beside the current
    model. `swap(processor)` puts a promoted candidate in the current model's place (`Pipeline.swap_processor`);
    `current()` is the model serving now; `factory` loads a candidate (None: this netapp cannot load one)."""

    def __init__(
        self,
        current: Callable[[], Processor],
        swap: Callable[[Processor], Any],
        factory: CandidateFactory | None,
        metrics: RolloutMetrics,
        lanes: int = 1,
    ) -> None:
        self.current = current
        self._swap = swap
        self.factory = factory
        self.metrics = metrics
        # Batches on `lanes` threads at once each take longer for sharing the cores: their summed times, over this,
        # are what the current model costs (under a lighter load it is an underestimate: the budget only tightens)
        self.lanes = max(1, lanes)
        self.phase = NONE
        self.reason: str | None = None
        self.model: str | None = None
        self.candidate: Processor | None = None
        self.policy = Policy()
        self.shadowing = Shadowing()
        self.sampler = Sampler(self.shadowing.sample, self.shadowing.budget)
        self.stats = ShadowStats(self.policy.window)
        self.same_input = False  # the candidate takes the current model's prepared frames
        self.started_at: float | None = None
        self.canary_frames = 0  # frames of canary robots the candidate answered
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="netapp-shadow")
        self._running = False  # a candidate frame (or its load) is on the shadow thread
        self._tasks: set[asyncio.Task] = set()
        metrics.watch(self)

    @property
    def active(self) -> bool:
        return self.phase in (SHADOW, CANARY)

    @property
    def needs_image(self) -> bool:
        """Whether sampled frames must keep their decoded picture (the candidate prepares its own input)."""
        return self.active and self.candidate is not None and not self.same_input

    # -- starting -----------------------------------------------------------------------------------------------

    def start(self, model: str, sha256: str | None, policy: Policy, shadowing: Shadowing) -> None:
        """Begin a rollout of `model`: loaded in the background; RolloutRefused when one is under way, the values
        are wrong, or this netapp cannot load a candidate."""
        problem = policy.problem() or shadowing.problem()
        if problem:
            raise RolloutRefused(problem)
        if self.factory is None:
            raise RolloutRefused("this netapp's processor loads its own weights: rollouts are for --model processors")
        if self.active:
            raise RolloutRefused(f"a rollout of {self.model} is under way: wait for its verdict (GET /rollout)")
        self.phase, self.reason, self.model, self.candidate = SHADOW, None, model, None
        self.policy, self.shadowing = policy, shadowing
        self.sampler = Sampler(shadowing.sample, shadowing.budget)
        self.stats = ShadowStats(policy.window)
        self.started_at = time.time()
        self.canary_frames = 0
        self._running = True  # nothing runs on the candidate until it is loaded
        self._spawn(self._load(model, sha256))
        log.info("rollout of %s: loading the candidate", model)

    async def _load(self, model: str, sha256: str | None) -> None:
        assert self.factory is not None
        try:
            candidate = await asyncio.get_running_loop().run_in_executor(self._pool, self.factory, model, sha256)
        except Exception as exc:  # whatever a bad file raises, the netapp goes on serving its current model
            self._conclude(ROLLED_BACK, f"the candidate failed to load: {exc}")
            return
        finally:
            self._running = False
        if self.phase != SHADOW or self.model != model:
            return  # stopped meanwhile
        self.candidate = candidate
        self.same_input = same_preparation(self.current(), candidate)
        log.info("rollout of %s: shadowing %.0f %% of frames", model, 100 * self.shadowing.sample)

    def _spawn(self, work: Any) -> None:
        task = asyncio.ensure_future(work)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        self._pool.shutdown(wait=False, cancel_futures=True)

    # -- the shadow -----------------------------------------------------------------------------------------------

    def keep_image(self, frame: Frame, image: Any) -> None:
        """On the thread that decodes a frame: keep its picture for the candidate when it prepares its own."""
        if self.needs_image:
            frame.shadow_image = image

    def after_batch(self, batch: Batch, outputs: list[Any], before_ns: int, after_ns: int) -> None:
        """On the event loop, once a batch's results have gone to their robots: the sampled frames go to the
        candidate (one at a time, within the budget)."""
        if not self.active or self.candidate is None:
            return
        current = self.current()
        served = [
            (s, f, o)
            for (s, f), o in zip(batch, outputs, strict=True)
            if not isinstance(o, FrameRejected) and f.processor in (None, current)  # a canary frame: the candidate's
        ]
        if not served:
            return
        current_s = (after_ns - before_ns) / 1e9 / len(served)
        self.sampler.current_ran(current_s * len(served) / self.lanes)
        for session, frame, output in served:
            frame_input = frame.prepared if self.same_input else frame.shadow_image
            frame.shadow_image = None
            if not self.sampler.wants() or frame_input is None:
                continue
            if self._running:
                self.stats.skip(SKIP_BUSY)
            elif not self.sampler.within_budget():
                self.stats.skip(SKIP_BUDGET)
            else:
                self._running = True
                self._spawn(self._shadow(session, frame_input, output, current_s))

    async def _shadow(self, session: Session, frame_input: Any, output: dict[str, Any], current_s: float) -> None:
        candidate = self.candidate
        try:
            if candidate is None:
                return
            loop = asyncio.get_running_loop()
            size = session.frame_size
            try:
                compared, seconds = await loop.run_in_executor(
                    self._pool, self._run_candidate, candidate, frame_input, session.args, output, size
                )
            except Exception as exc:
                log.warning("rollout of %s: the candidate failed on a frame: %r", self.model, exc)
                self.stats.failed(repr(exc))
            else:
                self.sampler.candidate_ran(seconds)
                self.stats.compared(compared, current_s, seconds)
        finally:
            self._running = False
        if candidate is self.candidate:
            await self._judge()

    def _run_candidate(
        self, candidate: Processor, frame_input: Any, args: Any, output: dict[str, Any], size: Any
    ) -> tuple[FrameAgreement, float]:
        """On the shadow thread: the candidate's answer for the frame (preparing it first when it prepares its
        own), timed, and compared with the current model's."""
        started = time.perf_counter()
        prepared = frame_input if self.same_input else candidate.prepare(frame_input, args)
        results = candidate.process([prepared])
        seconds = time.perf_counter() - started
        if len(results) != 1 or not isinstance(results[0], dict):
            raise RuntimeError(f"the candidate returned {len(results)} results for 1 frame")
        return compare_results(output, results[0], tuple(size) if size else None), seconds

    async def _judge(self) -> None:
        verdict = judge(self.phase, self.stats.evidence(), self.policy)
        if verdict.phase == self.phase:
            return
        if verdict.phase == CANARY:
            self.phase, self.reason = CANARY, verdict.reason
            self.stats.next_phase()
            log.info("rollout of %s: canary for %.0f %% of robots (%s)", self.model, 100 * self.policy.canary_share,
                     verdict.reason)  # fmt: skip
        elif verdict.phase == PROMOTED:
            candidate = self.candidate
            assert candidate is not None
            await self._swap(candidate)
            self._conclude(PROMOTED, verdict.reason)
        else:
            self._conclude(ROLLED_BACK, verdict.reason)

    def _conclude(self, phase: str, reason: str | None) -> None:
        assert phase in FINAL
        self.phase, self.reason = phase, reason
        self.candidate = None  # unloaded (promoted: it serves now, held by the pipeline)
        (log.info if phase == PROMOTED else log.warning)("rollout of %s: %s (%s)", self.model, phase, reason)
        self.metrics.verdict(phase)

    # -- the canary -----------------------------------------------------------------------------------------------

    def processor_for(self, session: Session) -> Processor | None:
        """The candidate, for a robot in the canary's share while the canary lasts (its results are then the
        candidate's); None: the current model."""
        candidate = self.candidate
        robot = session.robot_id or session.id  # a robot keeps its side across sessions when it names itself
        if self.phase == CANARY and candidate is not None and in_canary(robot, self.policy.canary_share):
            self.canary_frames += 1
            return candidate
        return None

    def processor_failed(self, error: str) -> None:
        """On an inference thread: a canary robot's frame failed on the candidate (its robot got the error): counted
        as the candidate's, and judged on the next comparison."""
        self.stats.failed(error)

    # -- what it shows --------------------------------------------------------------------------------------------

    def to_json(self) -> dict[str, Any]:
        """GET /rollout (docs/rollouts.md)."""
        evidence = self.stats.evidence()
        summary = self.stats.summary()
        return {
            "phase": self.phase,
            "model": self.model,
            "serving": self.current().name,
            "candidate_loaded": self.candidate is not None,
            "reason": self.reason,
            "frames_compared": self.stats.frames,
            "phase_frames": self.stats.phase_frames,
            "agreement": summary["f1"] if self.stats.frames else None,
            "mask_iou": summary["mask_iou"],
            "oks": summary["oks"],
            "p95_ms": {
                "current": _ms(evidence.p95_current_s),
                "candidate": _ms(evidence.p95_candidate_s),
            },
            "canary_frames": self.canary_frames,
            "errors": self.stats.errors,
            "last_error": self.stats.last_error,
            "skipped": dict(self.stats.skipped),
            "policy": asdict(self.policy),
            "shadow": asdict(self.shadowing),
            "started_at": self.started_at,
        }


def _ms(seconds: float | None) -> float | None:
    return None if seconds is None else round(seconds * 1000, 2)


__all__ = ["NONE", "PROMOTED", "ROLLED_BACK", "SHADOW", "CANARY", "Rollout", "RolloutRefused", "Shadowing"]
