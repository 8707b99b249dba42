"""The data path: newest-wins queues, one shared processor, fair batching across robots.

robot frame -> transport -> `admit()` (counted, ordered) -> `receive()` (decode and prepare on a small pool where
there are spare cores, else later on the inference thread) -> the session's queue (bounded, newest wins) -> ready
queue of sessions (round robin, so a fast robot cannot starve the others) -> a frame whose robot's deadline cannot
be met is dropped here, before inference is spent on it -> one inference thread (micro-batch across robots when the
processor allows it) -> result message -> the frame's waiter, its sink, or the session's polled results.

Every frame is counted here and only here: received, rejected, dropped and processed, in the session's counters
and the Prometheus metrics together, labelled by the transport the frame arrived on.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from netapp.sdk.processor import Processor
from netapp.server.capacity import CapacityEstimator
from netapp.server.errors import DeadlineMissed, FrameDropped, FrameError, FrameRejected, SessionClosed
from netapp.server.metrics import Metrics
from netapp.server.session_state import StateKeeper
from netapp.server.sessions import Session, SessionRegistry
from netapp.server.settings import Settings
from netapp.server.ui.live import LiveView

log = logging.getLogger(__name__)

# Batch times older than this are not trusted for deadlines: when every frame would be dropped, one is processed to
# measure again (at most one a second), so slow batches long ago cannot drop frames forever.
ESTIMATE_TTL_NS = 1_000_000_000


class ResultSink(Protocol):
    """Where a push transport sends what became of a frame (Socket.IO: the robot's connection)."""

    async def result(self, session: Session, message: dict[str, Any]) -> None: ...

    async def error(self, session: Session, timestamp: int | None, error: FrameError) -> None: ...


@dataclass(eq=False)  # a frame is itself: compared by identity (its prepared data may be an array)
class Frame:
    timestamp: int
    recv_ns: int
    seq: int
    transport: str  # the `transport` label of its metrics
    prepared: Any = None
    decode: Callable[[], Any] | None = None  # still to decode and prepare, on the inference thread
    waiter: asyncio.Future | None = None  # HTTP ?wait=true
    sink: ResultSink | None = None  # push transports; neither waiter nor sink: kept for polling
    image: np.ndarray | None = None  # the decoded frame, kept only while a page watches its robot
    answered: bool = False  # its result or error went out
    superseded: bool = False  # a newer frame of its robot took its place before it was prepared
    deadline_ms: float | None = None  # the robot's: its result must leave by recv_ns + deadline_ms

    def cannot_finish(self, now_ns: int, expected_ns: float) -> bool:
        """Would its result leave after its deadline if processing started now and took `expected_ns`?"""
        return self.deadline_ms is not None and now_ns + expected_ns > self.recv_ns + self.deadline_ms * 1e6


@dataclass
class SessionQueue:
    """A session's frames waiting for inference, and the order they were received in."""

    session: Session
    pending: deque[Frame] = field(default_factory=deque)
    queued: bool = False  # in the pipeline's ready queue
    busy: bool = False  # a frame of it is being processed: back in line once that is done, not before
    next_seq: int = 0
    last_seq: int = -1
    preparing: deque[tuple[Frame, asyncio.Future]] = field(default_factory=deque)  # on the prepare pool


class Pipeline:
    def __init__(
        self,
        processor: Processor,
        settings: Settings,
        metrics: Metrics,
        sessions: SessionRegistry,
        live: LiveView | None = None,
    ) -> None:
        self.processor = processor
        self.live = live
        self.settings = settings
        self.metrics = metrics
        self.sessions = sessions
        self.capacity = CapacityEstimator(
            default_robot_fps=settings.assumed_robot_fps, hard_share=settings.hard_share
        )  # fed each batch's busy time
        self.keeper = StateKeeper(processor, self.exclusive, settings.state_dir)
        self.ready = asyncio.Event()
        self._queues: dict[str, SessionQueue] = {}
        self._ready_queues: asyncio.Queue[SessionQueue] = asyncio.Queue()
        self._prepare_pool = (
            ThreadPoolExecutor(settings.prepare_threads, thread_name_prefix="netapp-prepare")
            if settings.prepare_threads > 0
            else None
        )
        # A stateful processor updates each session's state in frame order, and reads and replaces states between
        # batches (`exclusive`): one lane. A stateless one runs `lanes` batches at once.
        self.lanes = 1 if self.keeper.processor is not None else max(1, settings.lanes)
        self._infer_pool = ThreadPoolExecutor(self.lanes, thread_name_prefix="netapp-infer")
        self._workers: list[asyncio.Task] = []
        self._busy_lanes = 0  # batches on the inference threads now
        self._busy_lock = threading.Lock()
        self._telling: set[asyncio.Task] = set()  # data errors on their way to push robots
        # What recent batches took, dequeue to results (decoding on the inference thread included). A frame is
        # dropped for its deadline only when even the quickest of them would finish late: the netapp drops what it
        # cannot finish, not what it might (a few slow batches on a busy machine must not drop every frame).
        self._batch_ns: deque[int] = deque(maxlen=8)
        self._measured_at_ns = 0
        self.load_error: BaseException | None = None
        self.recent_latency_s = 0.0  # moving average of receive-to-result (a gauge to scale on)
        metrics.queue_depth.set_function(lambda: sum(len(q.pending) for q in list(self._queues.values())))
        metrics.recent_latency.set_function(lambda: self.recent_latency_s)

    @property
    def expected_batch_ns(self) -> int:
        """The quickest recent batch (0 before the first): what a frame's deadline is checked against."""
        return min(self._batch_ns, default=0)

    @property
    def max_batch(self) -> int:
        allowed = max(1, int(getattr(self.processor, "max_batch", 1)))
        return min(allowed, self.settings.max_batch) if self.settings.max_batch > 0 else allowed

    async def start(self) -> None:
        """Load the processor off the event loop; the app answers /healthz meanwhile and /readyz after."""
        loop = asyncio.get_running_loop()
        try:
            await loop.run_in_executor(self._infer_pool, self.processor.load)
        except BaseException as exc:
            self.load_error = exc
            raise
        self._workers = [asyncio.create_task(self._run(), name=f"netapp-inference-{i}") for i in range(self.lanes)]
        self.ready.set()

    async def exclusive(self, fn: Callable[..., Any], *args: Any) -> Any:
        """Run `fn` on the inference thread, between batches: where session states may be read and changed (a
        stateful processor has one lane, so this thread is the only one)."""
        return await asyncio.get_running_loop().run_in_executor(self._infer_pool, fn, *args)

    async def stop(self) -> None:
        for worker in self._workers:
            worker.cancel()
        for worker in self._workers:
            try:
                await worker
            except asyncio.CancelledError:
                pass
        for queue in list(self._queues.values()):
            self.clear(queue.session, SessionClosed("the netapp is shutting down"))
        if self._prepare_pool is not None:
            self._prepare_pool.shutdown(wait=False, cancel_futures=True)
        self._infer_pool.shutdown(wait=False, cancel_futures=True)

    # -- counting: the one place ----------------------------------------------------------------------------------

    def admit(self, session: Session | None, transport: str) -> int:
        """Count a frame received on `transport` (for `session`, when it has one) and return its receive order,
        fixed here before concurrent decoding can reorder frames."""
        self.metrics.received.labels(transport=transport).inc()
        if session is None:
            return 0
        session.admit(transport)
        queue = self._queue(session)
        queue.next_seq += 1
        return queue.next_seq

    def reject(self, session: Session | None, transport: str, reason: str) -> None:
        """Count a frame (or command) refused with an error to its sender."""
        if session is not None:
            session.rejected += 1
        self.metrics.reject(transport, reason)

    def _drop(self, session: Session, frame: Frame) -> None:
        session.dropped += 1
        self.metrics.dropped.labels(transport=frame.transport).inc()
        _resolve(frame.waiter, exc=FrameDropped())
        if frame.sink is not None and not session.closed:  # a push robot hears of it too: its slot is free
            task = asyncio.ensure_future(self._tell_dropped(session, frame))
            self._telling.add(task)
            task.add_done_callback(self._telling.discard)

    async def _tell_dropped(self, session: Session, frame: Frame) -> None:
        try:
            await frame.sink.error(session, frame.timestamp, FrameDropped())
        except Exception:
            log.exception("could not tell session %s of a superseded frame", session.id)

    def _count_deadline_dropped(self, session: Session, frame: Frame) -> None:
        session.deadline_dropped += 1
        self.metrics.deadline_dropped.labels(transport=frame.transport).inc()

    def _count_processed(self, session: Session, frame: Frame, now_ns: int) -> None:
        session.processed += 1
        self.metrics.processed.labels(transport=frame.transport).inc()
        latency = (now_ns - frame.recv_ns) / 1e9
        self.metrics.latency.labels(transport=frame.transport).observe(latency)
        self.recent_latency_s += 0.05 * (latency - self.recent_latency_s)

    # -- queues ---------------------------------------------------------------------------------------------------

    def _queue(self, session: Session) -> SessionQueue:
        queue = self._queues.get(session.id)
        if queue is None:
            queue = SessionQueue(session)
            if not session.closed:  # a closed session's queue would never be removed
                self._queues[session.id] = queue
        return queue

    def queues(self) -> int:
        """How many sessions have a queue (each open session that has sent a frame)."""
        return len(self._queues)

    def depth(self, session: Session) -> int:
        queue = self._queues.get(session.id)
        return len(queue.pending) if queue is not None else 0

    def clear(self, session: Session, exc: BaseException) -> None:
        """Take a session's waiting frames off its queue; their waiters get `exc`."""
        queue = self._queues.get(session.id)
        while queue is not None and queue.pending:
            _resolve(queue.pending.popleft().waiter, exc=exc)

    def close(self, session: Session, exc: BaseException) -> None:
        """Forget a session that is going away; the waiters of its frames get `exc`."""
        self.clear(session, exc)
        self._queues.pop(session.id, None)

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
    ) -> asyncio.Future | None:
        """Queue one admitted frame: decoded and prepared on the prepare pool first, or (no pool) on the inference
        thread right before its batch. Raises FrameRejected for input the server cannot take; with the inference
        thread decoding, such an error reaches the sender like a result (waiter, sink or the polled results).

        With `wait`, returns a future resolved with the frame's result message (or FrameDropped / DeadlineMissed /
        SessionClosed). `deadline_ms`: the robot's deadline for this frame, from `recv_ns`.
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
        )
        frame.waiter = loop.create_future() if wait else None
        if self._prepare_pool is not None:
            queue = self._queue(session)
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
                self._drop(session, frame)
                return frame.waiter
            finally:
                if (frame, job) in queue.preparing:
                    queue.preparing.remove((frame, job))
            frame.decode = None
        self._submit(session, frame)
        return frame.waiter

    def _prepare(self, session: Session, frame: Frame) -> Any:
        """Decode and prepare, on whichever thread does it; FrameRejected for a frame that cannot be, whatever
        was raised (a decoder's cv2.error or a processor's bug alike): its sender hears of it, nobody else."""
        try:
            image = frame.decode()
            if self.live is not None and self.live.watched(session.id):
                frame.image = image  # a reference, no copy: the page encodes it only if it asks
            return self.processor.prepare(image, session.args)
        except FrameRejected:
            raise
        except ValueError as exc:
            raise FrameRejected("bad_frame", str(exc)) from exc
        except Exception as exc:
            log.warning("preparing a frame of session %s failed: %r", session.id, exc)
            raise FrameRejected("prepare_failed", f"this frame could not be prepared: {exc!r}", 500) from exc

    def _submit(self, session: Session, frame: Frame) -> None:
        if session.closed:
            _resolve(frame.waiter, exc=SessionClosed("the session was closed"))
            return
        queue = self._queue(session)
        if frame.seq < queue.last_seq:
            self._drop(session, frame)  # a newer frame of this robot was queued while this one decoded
            return
        queue.last_seq = frame.seq
        while len(queue.pending) >= self.settings.queue_size:
            self._drop(session, queue.pending.popleft())
        queue.pending.append(frame)
        self._line_up(queue)

    def _line_up(self, queue: SessionQueue) -> None:
        """Into the ready queue, at the back, when it has a frame and none in process (so a robot never has two
        lanes, and its results leave in order)."""
        if queue.pending and not queue.queued and not queue.busy and not queue.session.closed:
            queue.queued = True
            self._ready_queues.put_nowait(queue)

    def _release(self, batch: list[tuple[Session, Frame]]) -> None:
        """A batch is done: its sessions may have their next frame processed."""
        for session, _ in batch:
            queue = self._queues.get(session.id)
            if queue is not None:
                queue.busy = False
                self._line_up(queue)

    # -- inference ------------------------------------------------------------------------------------------------

    async def _run(self) -> None:
        """One lane: keep its inference thread busy. With one lane, when a batch is done and another is ready, the
        next one starts before the done one's results are sent, so sending overlaps inference instead of leaving
        the thread idle; with more, the other lanes fill that gap (a frame taken early would only grow older). A
        robot has one frame in process at a time, whatever the lanes, so its results leave in order."""
        loop = asyncio.get_running_loop()
        running: tuple[list[tuple[Session, Frame]], asyncio.Future] | None = None
        while True:
            if running is None:
                batch = await self._next_batch()
                if not batch:
                    continue
                running = batch, loop.run_in_executor(self._infer_pool, self._run_batch, batch)
            batch, future = running
            running = None
            try:
                outputs = await future
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # never let one bad batch stop the server, nor leave its senders waiting
                log.exception("unexpected error while processing a batch")
                self._release(batch)
                await self._answer_unanswered(batch, exc)
                continue
            self._release(batch)
            if self.lanes == 1 and not self._ready_queues.empty():
                following = await self._collect([self._ready_queues.get_nowait()])
                if following:
                    running = following, loop.run_in_executor(self._infer_pool, self._run_batch, following)
            try:
                await self._deliver_batch(batch, *outputs)
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                log.exception("unexpected error while sending the results of a batch")
                await self._answer_unanswered(batch, exc)

    async def _answer_unanswered(self, batch: list[tuple[Session, Frame]], exc: Exception) -> None:
        error = FrameRejected("internal_error", f"internal error: {exc!r}", 500)
        for session, frame in batch:
            if not frame.answered:
                await self._error(session, frame, error)

    async def _next_batch(self) -> list[tuple[Session, Frame]]:
        return await self._collect([await self._ready_queues.get()])

    async def _collect(self, queues: list[SessionQueue]) -> list[tuple[Session, Frame]]:
        """A batch: the next frame of each of the first `max_batch` sessions in the ready queue (`queues` first)."""
        while len(queues) < self.max_batch and not self._ready_queues.empty():
            queues.append(self._ready_queues.get_nowait())
        batch, late = [], []
        now_ns = time.monotonic_ns()
        expected_ns = self.expected_batch_ns if now_ns - self._measured_at_ns < ESTIMATE_TTL_NS else 0
        for queue in queues:
            queue.queued = False
            while not queue.session.closed and queue.pending:
                frame = queue.pending.popleft()
                if not frame.cannot_finish(now_ns, expected_ns):
                    batch.append((queue.session, frame))
                    queue.busy = True  # back of the line once this frame is done: round robin between robots
                    break
                late.append((queue.session, frame))
        for session, frame in late:  # after the batch is taken, so its robots' replies wait for no one
            self._count_deadline_dropped(session, frame)
            assert frame.deadline_ms is not None
            miss = DeadlineMissed(frame.deadline_ms, (now_ns - frame.recv_ns) / 1e6, expected_ns / 1e6)
            await self._error(session, frame, miss)
        return batch

    def _run_batch(self, batch: list[tuple[Session, Frame]]) -> tuple[list[Any], int, int]:
        """On the inference thread: prepare what is still undecoded, then one `process` call for the rest.

        Returns one output or FrameRejected per frame, and the processing start and end (monotonic ns). The
        thread's whole busy time (decoding included) feeds the capacity estimate.
        """
        with self._busy_lock:
            self._busy_lanes += 1
            lanes_at_start = self._busy_lanes
        start = time.monotonic_ns()
        outputs: list[Any] = [None] * len(batch)
        ready: list[int] = []
        for i, (session, frame) in enumerate(batch):
            if frame.decode is not None:
                try:
                    frame.prepared = self._prepare(session, frame)
                except FrameRejected as exc:
                    outputs[i] = exc
                    continue
                frame.decode = None
            ready.append(i)
        before = time.monotonic_ns()
        if ready:
            try:
                results = self._process_frames([batch[i][1].prepared for i in ready])
            except Exception as exc:
                if len(ready) == 1:
                    log.warning("processing a frame failed: %r", exc)
                    results = [FrameRejected("processing_failed", f"processing failed: {exc!r}", 500)]
                else:  # one bad frame must not fail the others: each alone, so only the bad one fails
                    log.warning(
                        "processing a batch of %d frames failed (%r): retrying them one by one", len(ready), exc
                    )
                    results = [self._process_alone(batch[i][1].prepared) for i in ready]
            for i, result in zip(ready, results, strict=True):
                outputs[i] = self._after_process(*batch[i], result)
        after = time.monotonic_ns()
        with self._busy_lock:
            lanes_at_end = self._busy_lanes
            self._busy_lanes -= 1
        if ready:
            # Lanes share the cores: a batch beside another takes longer, and its share of the time is what one
            # result costs the netapp (the lanes busy at its start and end, averaged).
            sharing = (lanes_at_start + lanes_at_end) / 2
            self.capacity.observe_batch(len(ready), (after - start) / 1e9 / sharing)
            # What a batch takes now, for deciding whether a frame can still meet its deadline (on the loop).
            if start - self._measured_at_ns >= ESTIMATE_TTL_NS:  # stale: start again from this one
                self._batch_ns.clear()
            self._batch_ns.append(after - start)
            self._measured_at_ns = after
        return outputs, before, after

    def _after_process(self, session: Session, frame: Frame, result: Any) -> Any:
        """A stateful processor's per-session step, in the session's frame order (on the inference thread)."""
        if isinstance(result, FrameRejected) or session.state is None:
            return result
        try:
            return self.keeper.after_process(session.state, result, frame.timestamp)
        except Exception as exc:
            log.exception("the processor's state update failed for session %s", session.id)
            return FrameRejected("processing_failed", f"processing failed: {exc}", 500)

    def _process_frames(self, prepared: list[Any]) -> list[Any]:
        results = self.processor.process(prepared)
        if len(results) != len(prepared):
            raise RuntimeError(f"processor returned {len(results)} results for {len(prepared)} frames")
        return results

    def _process_alone(self, prepared: Any) -> Any:
        try:
            return self._process_frames([prepared])[0]
        except Exception as exc:
            log.warning("processing a frame failed: %r", exc)
            return FrameRejected("processing_failed", f"processing failed: {exc!r}", 500)

    async def _deliver_batch(
        self, batch: list[tuple[Session, Frame]], outputs: list[Any], before: int, after: int
    ) -> None:
        processed = sum(not isinstance(o, FrameRejected) for o in outputs)
        if processed:
            self.metrics.inference.observe((after - before) / 1e9)
            self.metrics.batch_size.observe(processed)
        for (session, frame), output in zip(batch, outputs, strict=True):
            if isinstance(output, FrameRejected):
                self.reject(session, frame.transport, output.reason)
                await self._error(session, frame, output)
                continue
            message = {
                "timestamp": frame.timestamp,
                "recv_timestamp": frame.recv_ns,
                "timestamp_before_process": before,
                "timestamp_after_process": after,
                **output,
                "dropped": session.dropped,
            }
            await self._deliver(session, frame, message)

    async def _deliver(self, session: Session, frame: Frame, message: dict[str, Any]) -> None:
        frame.answered = True
        message["send_timestamp"] = now = time.monotonic_ns()
        self._count_processed(session, frame, now)
        if self.live is not None:
            self.live.record(session, message, frame.image)
            frame.image = None
        if frame.waiter is not None:
            _resolve(frame.waiter, result=message)
        elif frame.sink is not None:
            if session.closed:
                return
            try:
                await frame.sink.result(session, message)
            except Exception:
                log.exception("could not send a result to session %s", session.id)
        else:
            self._keep(session, message)

    async def _error(self, session: Session, frame: Frame, error: FrameError) -> None:
        frame.answered = True
        if frame.waiter is not None:
            _resolve(frame.waiter, exc=error)
        elif frame.sink is not None:
            if not session.closed:
                try:
                    await frame.sink.error(session, frame.timestamp, error)
                except Exception:
                    log.exception("could not send an error to session %s", session.id)
        else:  # polling robots find the error where the result would have been
            self._keep(session, {"timestamp": frame.timestamp, "error": str(error), "reason": error.reason})

    def _keep(self, session: Session, message: dict[str, Any]) -> None:
        if session.keep_result(message):
            self.metrics.results_overflowed.inc()


def _resolve(waiter: asyncio.Future | None, result: Any = None, exc: BaseException | None = None) -> None:
    if waiter is None or waiter.done():
        return
    if exc is not None:
        waiter.set_exception(exc)
    else:
        waiter.set_result(result)
