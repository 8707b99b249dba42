"""What became of each frame goes back to its sender: the 5G-ERA result message (with the netapp's timestamps, the
robot's pacing fields among them), or the error that took its place, to the frame's waiter (HTTP `?wait=true`), its
transport's sink (Socket.IO, `frames`, RTP, WebRTC, a camera) or the session's polled results; and every delivered
result to the observers."""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

from netapp.protocol import HINT_FIELD, TRACE_CLOCK_FIELD
from netapp.results import MAX_RESULT_BYTES, bound_result
from netapp.sdk.processor import Processor
from netapp.server.errors import FrameDropped, FrameError, FrameRejected
from netapp.server.metrics import Metrics
from netapp.server.pipeline.counting import FrameCounter
from netapp.server.pipeline.frame import Frame, resolve
from netapp.server.pipeline.hints import advertised_size, result_hint
from netapp.server.pipeline.observers import Observers
from netapp.server.pipeline.scheduling import Batch
from netapp.server.pipeline.tracing import FrameTracing
from netapp.server.sessions import Session
from netapp.wire_json import dumpb

log = logging.getLogger(__name__)


class Delivery:
    """`next_turn(session, since_turn_s)`: seconds until the session's next turn, its last having started
    `since_turn_s` ago (the `next_frame_in_ms` of its result's hint; None: results leave it out)."""

    def __init__(
        self,
        counter: FrameCounter,
        metrics: Metrics,
        observers: Observers,
        processor: Processor,
        next_turn: Callable[[Session, float], float] | None = None,
        tracing: FrameTracing | None = None,
    ) -> None:
        self.counter = counter
        self.metrics = metrics
        self.observers = observers
        self.processor = processor
        self.next_turn = next_turn
        self.tracing = tracing  # a traced frame's spans are made once its result or error has gone
        self._telling: set[asyncio.Task] = set()  # data errors on their way to push robots
        self._logged: set[str] = set()  # reasons a result's field was refused, logged once each

    def drop(self, session: Session, frame: Frame) -> None:
        """A frame superseded by a newer one of its robot: counted, and its sender told."""
        self.counter.dropped(session, frame.transport)
        resolve(frame.waiter, exc=FrameDropped())
        if frame.sink is not None and not session.closed:  # a push robot hears of it too: its slot is free
            task = asyncio.ensure_future(self._tell_dropped(session, frame))
            self._telling.add(task)
            task.add_done_callback(self._telling.discard)

    async def _tell_dropped(self, session: Session, frame: Frame) -> None:
        try:
            await frame.sink.error(session, frame.timestamp, FrameDropped())
        except Exception:
            log.exception("could not tell session %s of a superseded frame", session.id)

    async def batch(self, batch: Batch, outputs: list[Any], before: int, after: int) -> None:
        """A processed batch's results (or each frame's error), in batch order."""
        processed = sum(not isinstance(o, FrameRejected) for o in outputs)
        if processed:
            self.metrics.inference.observe((after - before) / 1e9)
            self.metrics.batch_size.observe(processed)
        input_size = advertised_size(self.processor)  # read per batch: a processor may change its model
        for (session, frame), output in zip(batch, outputs, strict=True):
            if isinstance(output, FrameRejected):
                self.counter.rejected(session, frame.transport, output.reason)
                await self.error(session, frame, output)
                continue
            output = self.bounded(output)
            message = {
                "timestamp": frame.timestamp,
                "recv_timestamp": frame.recv_ns,
                "timestamp_before_process": before,
                "timestamp_after_process": after,
                **output,
                "dropped": session.dropped,
            }
            hint = self.hint(session, frame, input_size)
            if hint is not None:
                message[HINT_FIELD] = hint
            unsendable = unencodable(message)
            if unsendable is not None:  # the robot hears of it, and its in-flight slot is free again
                self.counter.rejected(session, frame.transport, unsendable.reason)
                await self.error(session, frame, unsendable)
                continue
            await self.deliver(session, frame, message)

    def bounded(self, output: dict[str, Any]) -> dict[str, Any]:
        """The processor's output as it may leave (`netapp.results.bound_result`): a mask, keypoints or rbox too big
        or malformed is never sent, and is counted by reason; the first of each reason is logged for its author."""
        output, refused = bound_result(output)
        counts = Counter(refused)
        counts.update(_taken(getattr(self.processor, "dropped", None)))
        for reason, count in counts.items():
            self.metrics.result_fields_refused.labels(reason=reason).inc(count)
            if reason not in self._logged:
                self._logged.add(reason)
                log.warning("%s: a result's field was refused (%s) and not sent", self.processor.name, reason)
        return output

    def hint(self, session: Session, frame: Frame, input_size: list[int] | None) -> dict[str, Any] | None:
        """The one place a result's `hint` is made (docs/server.md#hints): the processor's size, and when the netapp
        will take `session`'s next frame (`next_frame_in_ms`, from its turn's start: `next_turn`; never for a
        session on a shared work queue, whose next frame may go to another replica)."""
        next_frame_in_ms = None
        if self.next_turn is not None and not session.frames_spread:
            since_turn_s = (time.monotonic_ns() - frame.turn_ns) / 1e9 if frame.turn_ns else 0.0
            next_frame_in_ms = 1000 * self.next_turn(session, since_turn_s)
        return result_hint(input_size, next_frame_in_ms)

    async def deliver(self, session: Session, frame: Frame, message: dict[str, Any]) -> None:
        frame.answered = True
        message["send_timestamp"] = now = time.monotonic_ns()
        epoch_ns = 0
        if frame.trace is not None:
            message[TRACE_CLOCK_FIELD] = epoch_ns = FrameTracing.clock_ns()
        self.counter.processed(session, frame.transport, (now - frame.recv_ns) / 1e9)
        self.observers.record(session, message, frame.image)
        frame.image = None
        if frame.waiter is not None:
            resolve(frame.waiter, result=message)
        elif frame.sink is not None:
            if session.closed:
                return
            try:
                await frame.sink.result(session, message)
            except Exception:
                log.exception("could not send a result to session %s", session.id)
        else:
            self.keep(session, message)
        if frame.trace is not None and self.tracing is not None:
            self.tracing.finish(session, frame, message, now, epoch_ns)

    async def error(self, session: Session, frame: Frame, error: FrameError) -> None:
        frame.answered = True
        if frame.trace is not None and self.tracing is not None:
            self.tracing.failed(session, frame, error.reason, time.monotonic_ns())
        if frame.waiter is not None:
            resolve(frame.waiter, exc=error)
        elif frame.sink is not None:
            if not session.closed:
                try:
                    await frame.sink.error(session, frame.timestamp, error)
                except Exception:
                    log.exception("could not send an error to session %s", session.id)
        else:  # polling robots find the error where the result would have been
            self.keep(session, error.event(frame.timestamp))

    async def answer_unanswered(self, batch: Batch, exc: Exception) -> None:
        """Whatever went wrong with a batch, each of its frames still gets an answer."""
        error = FrameRejected("internal_error", f"internal error: {exc!r}", 500)
        for session, frame in batch:
            if not frame.answered:
                await self.error(session, frame, error)

    def keep(self, session: Session, message: dict[str, Any]) -> None:
        if session.keep_result(message):
            self.metrics.results_overflowed.inc()


def _taken(dropped: Counter[str] | None) -> Counter[str]:
    """What a processor left out of its results since last asked, by reason (the model processor's `dropped`: a
    detection whose decoding failed), emptied as it is taken."""
    if not isinstance(dropped, Counter) or not dropped:
        return Counter()
    taken = Counter(dropped)
    dropped.clear()
    return taken


def unencodable(message: dict[str, Any]) -> FrameRejected | None:
    """Why a result cannot go to its robot (it cannot be encoded as JSON: nested past 255, an object JSON has no form
    for; or it is over `MAX_RESULT_BYTES` encoded), as the error that goes instead; None when it can. Encoded once
    more here (a result of 30 detections in about 8 us), so that every transport's sink is spared the failure."""
    try:
        size = len(dumpb(message))
    except (TypeError, ValueError) as exc:  # orjson's JSONEncodeError is a TypeError
        return FrameRejected("result_unencodable", f"the processor's result cannot be encoded as JSON ({exc})", 500)
    if size > MAX_RESULT_BYTES:
        return FrameRejected(
            "result_too_big", f"the processor's result is {size} bytes encoded, over {MAX_RESULT_BYTES}", 500
        )
    return None
