"""The data path inside the netapp, put together: newest-wins queues, one shared processor, fair batching.

robot frame -> the dataplane -> `admit()` (counted, ordered) -> `receive()` (decode and prepare on a small pool where
there are spare cores, else later on the inference thread) -> the session's queue (`scheduling`: bounded, newest
wins) -> ready queue of sessions (round robin, so a fast robot cannot starve the others) -> a frame whose robot's
deadline cannot be met is dropped there, before inference is spent on it -> the inference threads (`lanes`:
micro-batch across robots when the processor allows it) -> result message (`delivery`) -> the frame's waiter, its
sink, or the session's polled results; and to the observers (`observers`). A hook (`hooks`: a model rollout) rides
along: it sees each frame as it is prepared and each batch after its results have gone.

Every frame is counted in one place (`counting`), labelled by the transport the frame arrived on.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from netapp.sdk.processor import Processor
from netapp.server.capacity import CapacityEstimator
from netapp.server.errors import DeadlineMissed, FrameRejected, SessionClosed
from netapp.server.metrics import Metrics
from netapp.server.pipeline.counting import FrameCounter
from netapp.server.pipeline.delivery import Delivery
from netapp.server.pipeline.frame import Frame, FrameTrace, ResultSink
from netapp.server.pipeline.hooks import InferenceHook
from netapp.server.pipeline.lanes import InferenceLanes
from netapp.server.pipeline.observers import Observers
from netapp.server.pipeline.scheduling import Batch, Scheduler, SessionQueue
from netapp.server.pipeline.state_keeper import StateKeeper
from netapp.server.pipeline.tracing import FrameTracing
from netapp.server.sessions import Session, SessionRegistry
from netapp.server.settings import Settings

log = logging.getLogger(__name__)


class Pipeline:
    def __init__(
        self,
        processor: Processor,
        settings: Settings,
        metrics: Metrics,
        sessions: SessionRegistry,
        tracing: FrameTracing | None = None,
    ) -> None:
        self.processor = processor
        self.tracing = tracing  # sampled frames' spans (docs/tracing.md); None: tracing is off
        self.settings = settings
        self.metrics = metrics
        self.sessions = sessions
        self.observers = Observers()  # who else sees the results (the web page's live view)
        self.capacity = CapacityEstimator(
            default_robot_fps=settings.assumed_robot_fps,
            hard_share=settings.hard_share,
            min_batches=settings.warm_batches,
        )  # fed each batch's busy time
        self.keeper = StateKeeper(processor, self.exclusive, settings.state_dir)
        self.ready = asyncio.Event()
        self.counter = FrameCounter(metrics)
        self.delivery = Delivery(
            self.counter,
            metrics,
            self.observers,
            processor,
            self._next_turn if settings.next_turn_hint else None,
            tracing,
        )
        self.scheduler = Scheduler(settings.queue_size, self.delivery.drop, settings.priority_weights)
        self._prepare_pool = (
            ThreadPoolExecutor(settings.prepare_threads, thread_name_prefix="netapp-prepare")
            if settings.prepare_threads > 0
            else None
        )
        # A stateful processor updates each session's state in frame order, and reads and replaces states between
        # batches (`exclusive`): one lane. A stateless one runs `lanes` batches at once.
        self.lanes = 1 if self.keeper.processor is not None else max(1, settings.lanes)
        self.inference = InferenceLanes(processor, self.keeper, self.lanes, self.capacity, self._prepare)
        self._workers: list[asyncio.Task] = []
        self.load_error: BaseException | None = None
        self.hook: InferenceHook | None = None  # what rides along the inference path (`attach`)
        metrics.queue_depth.set_function(self.scheduler.waiting)

    def attach(self, hook: InferenceHook) -> None:
        """Let `hook` ride along the inference path (a model rollout: docs/rollouts.md); one at a time."""
        self.hook = hook
        self.inference.processor_failed = hook.processor_failed

    def _next_turn(self, session: Session, since_turn_s: float) -> float:
        """Seconds until `session`'s next turn (the hint of its result; `Scheduler.next_turn_in_s`)."""
        return self.scheduler.next_turn_in_s(session, since_turn_s, time.monotonic())

    @property
    def max_batch(self) -> int:
        allowed = max(1, int(getattr(self.processor, "max_batch", 1)))
        return min(allowed, self.settings.max_batch) if self.settings.max_batch > 0 else allowed

    @property
    def recent_latency_s(self) -> float:
        """Moving average of receive-to-result (a gauge to scale on)."""
        return self.counter.recent_latency_s

    async def start(self) -> None:
        """Load the processor off the event loop; the app answers /healthz meanwhile and /readyz after."""
        try:
            await self.inference.exclusive(self.processor.load)
        except BaseException as exc:
            self.load_error = exc
            raise
        self._workers = [asyncio.create_task(self._run(), name=f"netapp-inference-{i}") for i in range(self.lanes)]
        self.ready.set()

    async def exclusive(self, fn: Callable[..., Any], *args: Any) -> Any:
        """Run `fn` on the inference thread, between batches (see `InferenceLanes.exclusive`)."""
        return await self.inference.exclusive(fn, *args)

    def swap_processor(self, processor: Processor) -> None:
        """Serve `processor` from the next batch on (a promoted candidate, already loaded): the batches in flight
        finish on the one they started with, and sessions, queues and states stay as they are."""
        self.processor = processor
        self.inference.processor = processor
        self.delivery.processor = processor
        if self.keeper.processor is not None:
            self.keeper.processor = processor

    async def stop(self) -> None:
        if self.hook is not None:
            self.hook.stop()
        for worker in self._workers:
            worker.cancel()
        for worker in self._workers:
            try:
                await worker
            except asyncio.CancelledError:
                pass
        for session in self.scheduler.sessions():
            self.clear(session, SessionClosed("the netapp is shutting down"))
        if self._prepare_pool is not None:
            self._prepare_pool.shutdown(wait=False, cancel_futures=True)
        self.inference.shutdown()

    # -- counting, and the queues the transports see ----------------------------------------------------------------

    def admit(self, session: Session | None, transport: str) -> int:
        """Count a frame received on `transport` (for `session`, when it has one) and return its receive order,
        fixed here before concurrent decoding can reorder frames."""
        self.counter.received(session, transport)
        return self.scheduler.next_seq(session) if session is not None else 0

    def reject(self, session: Session | None, transport: str, reason: str) -> None:
        """Count a frame (or command) refused with an error to its sender."""
        self.counter.rejected(session, transport, reason)

    def queues(self) -> int:
        """How many sessions have a queue (each open session that has sent a frame)."""
        return self.scheduler.queues()

    def depth(self, session: Session) -> int:
        return self.scheduler.depth(session)

    def clear(self, session: Session, exc: BaseException) -> None:
        """Take a session's waiting frames off its queue; their waiters get `exc`."""
        self.scheduler.clear(session, exc)

    def close(self, session: Session, exc: BaseException) -> None:
        """Forget a session that is going away; the waiters of its frames get `exc`."""
        self.scheduler.close(session, exc)

    # -- receiving --------------------------------------------------------------------------------------------------

    async def receive(
        self,
        session: Session,
        transport: str,
        seq: int,
        timestamp: int,
        decode: Callable[[], np.ndarray],
        *,
        wait: bool = False,
        sink: ResultSink | None = None,
        recv_ns: int | None = None,
        deadline_ms: float | None = None,
        in_order: bool = False,
        trace: FrameTrace | None = None,
    ) -> asyncio.Future | None:
        """Queue one admitted frame: decoded and prepared on the prepare pool first, or (no pool) on the inference
        thread right before its batch. Raises FrameRejected for input the server cannot take; with the inference
        thread decoding, such an error reaches the sender like a result (waiter, sink or the polled results).

        With `wait`, returns a future resolved with the frame's result message (or FrameDropped / DeadlineMissed /
        SessionClosed). `deadline_ms`: the robot's deadline for this frame, from `recv_ns`. `in_order`: its decoding
        needs its robot's earlier frames decoded first (video), so it runs on the inference thread that runs the
        frame, where a robot has one frame at a time, never on the pool.
        """
        recv_ns = recv_ns if recv_ns is not None else time.monotonic_ns()
        if not self.ready.is_set():
            raise FrameRejected("not_ready", "the model is still loading; retry when /readyz answers 200", 503)

        loop = asyncio.get_running_loop()
        frame = Frame(
            timestamp=timestamp,
            recv_ns=recv_ns,
            seq=seq,
            transport=transport,
            decode=decode,
            sink=sink,
            deadline_ms=deadline_ms,
            trace=trace,
        )
        frame.waiter = loop.create_future() if wait else None
        if self._prepare_pool is not None and not in_order:
            queue = self.scheduler.queue(session)
            # Newest wins here too: a robot flooding the shared pool displaces its own waiting frames, nobody
            # else's, and holds at most queue_size + 1 frames there.
            while len(queue.preparing) > self.settings.queue_size:
                older, job = queue.preparing.popleft()
                older.superseded = True
                job.cancel()
            job = loop.run_in_executor(self._prepare_pool, self._prepare, session, frame)
            queue.preparing.append((frame, job))
            try:
                frame.prepared = await job
            except asyncio.CancelledError:
                if not frame.superseded:
                    raise
                self.delivery.drop(session, frame)
                return frame.waiter
            finally:
                if (frame, job) in queue.preparing:
                    queue.preparing.remove((frame, job))
            frame.decode = None
        self.scheduler.submit(session, frame)
        return frame.waiter

    def _prepare(self, session: Session, frame: Frame) -> Any:
        """Decode and prepare, on whichever thread does it; FrameRejected for a frame that cannot be, whatever
        was raised (a decoder's cv2.error or a processor's bug alike): its sender hears of it, nobody else."""
        try:
            started = time.monotonic_ns() if frame.trace is not None else 0
            image = frame.decode()
            if started:
                frame.decoded_ns = (started, time.monotonic_ns())
            session.frame_size = (int(image.shape[1]), int(image.shape[0]))
            if self.observers.watched(session.id):
                frame.image = image  # a reference, no copy: the page encodes it only if it asks
            processor = self.processor
            if self.hook is not None:
                self.hook.keep_image(frame, image)
                processor = self.hook.processor_for(session) or processor
            frame.processor = processor
            return processor.prepare(image, session.args)
        except FrameRejected:
            raise
        except ValueError as exc:
            raise FrameRejected("bad_frame", str(exc)) from exc
        except Exception as exc:
            log.warning("preparing a frame of session %s failed: %r", session.id, exc)
            raise FrameRejected("prepare_failed", f"this frame could not be prepared: {exc!r}", 500) from exc

    # -- the lanes' loop --------------------------------------------------------------------------------------------

    async def _run(self) -> None:
        """One lane: keep its inference thread busy. With one lane, when a batch is done and another is ready, the
        next one starts before the done one's results are sent, so sending overlaps inference instead of leaving
        the thread idle; with more, the other lanes fill that gap (a frame taken early would only grow older). A
        robot has one frame in process at a time, whatever the lanes, so its results leave in order."""
        running: tuple[Batch, asyncio.Future] | None = None
        while True:
            if running is None:
                batch = await self._collect([await self.scheduler.next_ready()])
                if not batch:
                    continue
                running = batch, self.inference.start(batch)
            batch, future = running
            running = None
            try:
                outputs = await future
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # never let one bad batch stop the server, nor leave its senders waiting
                log.exception("unexpected error while processing a batch")
                self.scheduler.release(batch)
                await self.delivery.answer_unanswered(batch, exc)
                continue
            self.scheduler.release(batch)
            if self.lanes == 1 and self.scheduler.has_ready():
                following = await self._collect([self.scheduler.take_ready()])
                if following:
                    running = following, self.inference.start(following)
            try:
                await self.delivery.batch(batch, *outputs)
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                log.exception("unexpected error while sending the results of a batch")
                await self.delivery.answer_unanswered(batch, exc)
            if self.hook is not None:  # after the robots have their results: the hook never delays them
                self.hook.after_batch(batch, *outputs)

    async def _collect(self, queues: list[SessionQueue]) -> Batch:
        """The next batch (see `Scheduler.collect`); the frames too late for their deadline are answered first."""
        now_ns = time.monotonic_ns()
        expected_ns = self.inference.expected_ns(now_ns)
        batch, late = self.scheduler.collect(queues, self.max_batch, now_ns, expected_ns)
        for session, frame in late:  # after the batch is taken, so its robots' replies wait for no one
            self.counter.deadline_dropped(session, frame.transport)
            assert frame.deadline_ms is not None
            miss = DeadlineMissed(frame.deadline_ms, (now_ns - frame.recv_ns) / 1e6, expected_ns / 1e6)
            await self.delivery.error(session, frame, miss)
        return batch
