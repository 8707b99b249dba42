"""The data path: newest-wins queues, one shared processor, fair batching across robots.

robot frame -> transport -> `receive()` (decode and prepare on a small pool where there are spare cores, else
later on the inference thread) -> session queue (bounded, newest wins) -> ready queue of sessions (round robin,
so a fast robot cannot starve the others) -> one inference thread (micro-batch across robots when the processor
allows it) -> result message -> the session's sink.
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
from netapp.server.errors import FrameDropped, FrameRejected, SessionClosed
from netapp.server.metrics import Metrics
from netapp.server.session_state import StateKeeper
from netapp.server.sessions import Frame, Session, SessionRegistry
from netapp.server.settings import Settings

log = logging.getLogger(__name__)


class Pipeline:
    def __init__(self, processor: Processor, settings: Settings, metrics: Metrics, sessions: SessionRegistry) -> None:
        self.processor = processor
        self.settings = settings
        self.metrics = metrics
        self.sessions = sessions
        self.keeper = StateKeeper(processor, settings.state_dir)
        self.ready = asyncio.Event()
        self._ready_sessions: asyncio.Queue[Session] = asyncio.Queue()
        self._prepare_pool = (
            ThreadPoolExecutor(settings.prepare_threads, thread_name_prefix="netapp-prepare")
            if settings.prepare_threads > 0
            else None
        )
        self._infer_pool = ThreadPoolExecutor(1, thread_name_prefix="netapp-infer")
        self._worker: asyncio.Task | None = None
        self.load_error: BaseException | None = None
        metrics.queue_depth.set_function(lambda: sum(len(s.pending) for s in sessions))

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
        self._worker = asyncio.create_task(self._run(), name="netapp-inference")
        self.ready.set()

    async def exclusive(self, fn: Callable[..., Any], *args: Any) -> Any:
        """Run `fn` on the inference thread, between batches: where session states may be read and changed."""
        return await asyncio.get_running_loop().run_in_executor(self._infer_pool, fn, *args)

    async def stop(self) -> None:
        if self._worker is not None:
            self._worker.cancel()
            try:
                await self._worker
            except asyncio.CancelledError:
                pass
        for session in self.sessions:
            self.fail_pending(session, SessionClosed("the netapp is shutting down"))
        if self._prepare_pool is not None:
            self._prepare_pool.shutdown(wait=False, cancel_futures=True)
        self._infer_pool.shutdown(wait=False, cancel_futures=True)

    async def receive(
        self,
        session: Session,
        timestamp: int,
        decode: Callable[[], np.ndarray],
        *,
        wait: bool = False,
        recv_ns: int | None = None,
        seq: int | None = None,
    ) -> asyncio.Future | None:
        """Queue one frame: decoded and prepared on the prepare pool first, or (no pool) on the inference thread
        right before its batch. Raises FrameRejected for input the server cannot take; with the inference thread
        decoding, such an error reaches the sender like a result (waiter, data_error or the polled results).

        With `wait`, returns a future resolved with the frame's result message (or FrameDropped / SessionClosed).
        """
        recv_ns = recv_ns if recv_ns is not None else time.monotonic_ns()
        seq = seq if seq is not None else session.take_seq()
        if not self.ready.is_set():
            raise FrameRejected("not_ready", "the model is still loading; retry when /readyz answers 200", 503)

        frame = Frame(timestamp=timestamp, recv_ns=recv_ns, seq=seq, decode=decode)
        if self._prepare_pool is not None:
            loop = asyncio.get_running_loop()
            frame.prepared = await loop.run_in_executor(self._prepare_pool, self._prepare, session, frame)
            frame.decode = None
        frame.waiter = asyncio.get_running_loop().create_future() if wait else None
        self._submit(session, frame)
        return frame.waiter

    def _prepare(self, session: Session, frame: Frame) -> Any:
        """Decode and prepare, on whichever thread does it; FrameRejected for a frame that cannot be."""
        try:
            return self.processor.prepare(frame.decode(), session.args)
        except FrameRejected:
            raise
        except ValueError as exc:
            raise FrameRejected("bad_frame", str(exc)) from exc

    def _submit(self, session: Session, frame: Frame) -> None:
        if session.closed:
            _resolve(frame.waiter, exc=SessionClosed("the session was closed"))
            return
        if frame.seq < session.last_seq:
            self._drop(session, frame)  # a newer frame of this robot was queued while this one decoded
            return
        session.last_seq = frame.seq
        while len(session.pending) >= session.queue_size:
            self._drop(session, session.pending.popleft())
        session.pending.append(frame)
        if not session.queued:
            session.queued = True
            self._ready_sessions.put_nowait(session)

    def _drop(self, session: Session, frame: Frame) -> None:
        session.dropped += 1
        self.metrics.dropped.labels(transport=session.transport).inc()
        _resolve(frame.waiter, exc=FrameDropped())

    def fail_pending(self, session: Session, exc: BaseException) -> None:
        """Resolve the waiters of a session that is going away."""
        while session.pending:
            _resolve(session.pending.popleft().waiter, exc=exc)

    async def _run(self) -> None:
        while True:
            batch = await self._next_batch()
            if not batch:
                continue
            try:
                await self._process(batch)
            except asyncio.CancelledError:
                raise
            except Exception:  # never let one bad batch stop the server
                log.exception("unexpected error while processing a batch")

    async def _next_batch(self) -> list[tuple[Session, Frame]]:
        sessions = [await self._ready_sessions.get()]
        while len(sessions) < self.max_batch and not self._ready_sessions.empty():
            sessions.append(self._ready_sessions.get_nowait())
        batch = []
        for session in sessions:
            session.queued = False
            if session.closed or not session.pending:
                continue
            batch.append((session, session.pending.popleft()))
            if session.pending:  # back of the line: round robin between robots
                session.queued = True
                self._ready_sessions.put_nowait(session)
        return batch

    def _run_batch(self, batch: list[tuple[Session, Frame]]) -> tuple[list[Any], int, int]:
        """On the inference thread: prepare what is still undecoded, then one `process` call for the rest.

        Returns one output or FrameRejected per frame, and the processing start and end (monotonic ns).
        """
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
                results = self.processor.process([batch[i][1].prepared for i in ready])
                if len(results) != len(ready):
                    raise RuntimeError(f"processor returned {len(results)} results for {len(ready)} frames")
            except Exception as exc:  # the senders hear of it; the server carries on
                log.exception("processor failed on a batch of %d frames", len(ready))
                results = [FrameRejected("processing_failed", f"processing failed: {exc}", 500)] * len(ready)
            for i, result in zip(ready, results, strict=True):
                outputs[i] = self._after_process(*batch[i], result)
        return outputs, before, time.monotonic_ns()

    def _after_process(self, session: Session, frame: Frame, result: Any) -> Any:
        """A stateful processor's per-session step, in the session's frame order (on the inference thread)."""
        if isinstance(result, FrameRejected) or session.state is None:
            return result
        try:
            return self.keeper.after_process(session.state, result, frame.timestamp)
        except Exception as exc:
            log.exception("the processor's state update failed for session %s", session.id)
            return FrameRejected("processing_failed", f"processing failed: {exc}", 500)

    async def _process(self, batch: list[tuple[Session, Frame]]) -> None:
        loop = asyncio.get_running_loop()
        outputs, before, after = await loop.run_in_executor(self._infer_pool, self._run_batch, batch)
        processed = sum(not isinstance(o, FrameRejected) for o in outputs)
        if processed:
            self.metrics.inference.observe((after - before) / 1e9)
            self.metrics.batch_size.observe(processed)
        for (session, frame), output in zip(batch, outputs, strict=True):
            if isinstance(output, FrameRejected):
                session.rejected += 1
                self.metrics.reject(session.transport, output.reason)
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
        message["send_timestamp"] = now = time.monotonic_ns()
        session.processed += 1
        self.metrics.processed.labels(transport=session.transport).inc()
        self.metrics.latency.labels(transport=session.transport).observe((now - frame.recv_ns) / 1e9)
        if frame.waiter is not None:
            _resolve(frame.waiter, result=message)
        elif session.send_result is not None and not session.closed:
            try:
                await session.send_result(session, message)
            except Exception:
                log.exception("could not send a result to session %s", session.id)
        else:
            self._keep(session, message)

    async def _error(self, session: Session, frame: Frame, error: FrameRejected) -> None:
        if frame.waiter is not None:
            _resolve(frame.waiter, exc=error)
        elif session.send_error is not None:
            if not session.closed:
                try:
                    await session.send_error(session, frame.timestamp, error)
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
