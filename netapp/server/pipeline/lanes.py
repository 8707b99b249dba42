"""The inference threads ("lanes"): a batch runs on one of them, decoding what is still undecoded, then one
`process` call, then a stateful processor's per-session update. Their busy time feeds the capacity estimate, and the
quickest recent batch tells the scheduler which frames can no longer meet their deadline."""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from netapp.sdk.processor import Processor
from netapp.server.capacity import CapacityEstimator
from netapp.server.errors import FrameRejected
from netapp.server.pipeline.frame import Frame
from netapp.server.pipeline.scheduling import Batch
from netapp.server.pipeline.state_keeper import StateKeeper
from netapp.server.sessions import Session

log = logging.getLogger(__name__)

# Batch times older than this are not trusted for deadlines: when every frame would be dropped, one is processed to
# measure again (at most one a second), so slow batches long ago cannot drop frames forever.
ESTIMATE_TTL_NS = 1_000_000_000

Outputs = tuple[list[Any], int, int]  # one output or FrameRejected per frame; processing start and end (ns)


class InferenceLanes:
    """`count` inference threads running batches of `processor`; `prepare(session, frame)` decodes and prepares a
    frame that was not prepared ahead."""

    def __init__(
        self,
        processor: Processor,
        keeper: StateKeeper,
        count: int,
        capacity: CapacityEstimator,
        prepare: Callable[[Session, Frame], Any],
    ) -> None:
        self.processor = processor
        self.keeper = keeper
        self.count = count
        self.capacity = capacity
        self._prepare = prepare
        self.pool = ThreadPoolExecutor(count, thread_name_prefix="netapp-infer")
        self._busy = 0  # batches on the inference threads now
        self._busy_lock = threading.Lock()
        # What recent batches took, dequeue to results (decoding on the inference thread included). A frame is
        # dropped for its deadline only when even the quickest of them would finish late: the netapp drops what it
        # cannot finish, not what it might (a few slow batches on a busy machine must not drop every frame).
        self._batch_ns: deque[int] = deque(maxlen=8)
        self._measured_at_ns = 0
        # told of a frame that a processor not its own (a hook's: `Pipeline.attach`) failed
        self.processor_failed: Callable[[str], None] | None = None

    @property
    def expected_batch_ns(self) -> int:
        """The quickest recent batch (0 before the first): what a frame's deadline is checked against."""
        return min(self._batch_ns, default=0)

    def expected_ns(self, now_ns: int) -> int:
        """`expected_batch_ns` while it is fresh, else 0 (no frame is dropped on an old measurement)."""
        return self.expected_batch_ns if now_ns - self._measured_at_ns < ESTIMATE_TTL_NS else 0

    async def exclusive(self, fn: Callable[..., Any], *args: Any) -> Any:
        """Run `fn` on an inference thread, between batches: where session states may be read and changed (a
        stateful processor has one lane, so this thread is the only one)."""
        return await asyncio.get_running_loop().run_in_executor(self.pool, fn, *args)

    def start(self, batch: Batch) -> asyncio.Future[Outputs]:
        return asyncio.get_running_loop().run_in_executor(self.pool, self.run_batch, batch)

    def shutdown(self) -> None:
        self.pool.shutdown(wait=False, cancel_futures=True)

    def run_batch(self, batch: Batch) -> Outputs:
        """On an inference thread: prepare what is still undecoded, then one `process` call for the rest.

        Returns one output or FrameRejected per frame, and the processing start and end (monotonic ns). The
        thread's whole busy time (decoding included) feeds the capacity estimate.
        """
        with self._busy_lock:
            self._busy += 1
            lanes_at_start = self._busy
        start = time.monotonic_ns()
        outputs: list[Any] = [None] * len(batch)
        ready: list[int] = []
        prepare_ns = [0] * len(batch)  # each frame's decoding and preparing here, for its session's cost
        for i, (session, frame) in enumerate(batch):
            frame.turn_ns = start
            if frame.decode is not None:
                prepared_at = time.monotonic_ns()
                try:
                    frame.prepared = self._prepare(session, frame)
                except FrameRejected as exc:
                    outputs[i] = exc
                    continue
                finally:
                    prepare_ns[i] = time.monotonic_ns() - prepared_at
                frame.decode = None
            ready.append(i)
        before = time.monotonic_ns()
        for processor, group in self._by_processor(batch, ready):
            results = self._process_group(processor, [batch[i][1].prepared for i in group])
            if processor is not self.processor and self.processor_failed is not None:
                for result in results:
                    if isinstance(result, FrameRejected):
                        self.processor_failed(str(result))
            for i, result in zip(group, results, strict=True):
                outputs[i] = self._after_process(*batch[i], result)
        after = time.monotonic_ns()
        with self._busy_lock:
            lanes_at_end = self._busy
            self._busy -= 1
        if ready:
            # Lanes share the cores: a batch beside another takes longer, and its share of the time is what one
            # result costs the netapp (the lanes busy at its start and end, averaged).
            sharing = (lanes_at_start + lanes_at_end) / 2
            self.capacity.observe_batch(len(ready), (after - start) / 1e9 / sharing)
            share_ns = (after - before) / len(ready)  # the model's call, shared by its frames
            for i in ready:
                batch[i][0].cost((prepare_ns[i] + share_ns) / 1e9 / sharing)
            # What a batch takes now, for deciding whether a frame can still meet its deadline (on the loop).
            if start - self._measured_at_ns >= ESTIMATE_TTL_NS:  # stale: start again from this one
                self._batch_ns.clear()
            self._batch_ns.append(after - start)
            self._measured_at_ns = after
        return outputs, before, after

    def _by_processor(self, batch: Batch, ready: list[int]) -> list[tuple[Processor, list[int]]]:
        """The ready frames grouped by the processor that prepared them (a rollout's canary robots' frames go to the
        candidate; a frame prepared before a swap finishes on the model it was prepared for)."""
        groups: dict[int, tuple[Processor, list[int]]] = {}
        for i in ready:
            processor = batch[i][1].processor or self.processor
            groups.setdefault(id(processor), (processor, []))[1].append(i)
        return list(groups.values())

    def _process_group(self, processor: Processor, prepared: list[Any]) -> list[Any]:
        """One `process` call for frames of one processor; one bad frame must not fail the others: on an error the
        frames go again one by one, so only the bad one fails."""
        try:
            return self._process_frames(processor, prepared)
        except Exception as exc:
            if len(prepared) == 1:
                log.warning("processing a frame failed: %r", exc)
                return [FrameRejected("processing_failed", f"processing failed: {exc!r}", 500)]
            log.warning("processing a batch of %d frames failed (%r): retrying them one by one", len(prepared), exc)
            return [self._process_alone(processor, p) for p in prepared]

    def _after_process(self, session: Session, frame: Frame, result: Any) -> Any:
        """A stateful processor's per-session step, in the session's frame order (on the inference thread)."""
        if isinstance(result, FrameRejected) or session.state is None:
            return result
        try:
            return self.keeper.after_process(session.state, result, frame.timestamp)
        except Exception as exc:
            log.exception("the processor's state update failed for session %s", session.id)
            return FrameRejected("processing_failed", f"processing failed: {exc}", 500)

    def _process_frames(self, processor: Processor, prepared: list[Any]) -> list[Any]:
        results = processor.process(prepared)
        if len(results) != len(prepared):
            raise RuntimeError(f"processor returned {len(results)} results for {len(prepared)} frames")
        return results

    def _process_alone(self, processor: Processor, prepared: Any) -> Any:
        try:
            return self._process_frames(processor, [prepared])[0]
        except Exception as exc:
            log.warning("processing a frame failed: %r", exc)
            return FrameRejected("processing_failed", f"processing failed: {exc!r}", 500)
