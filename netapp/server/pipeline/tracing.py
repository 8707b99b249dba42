"""The netapp's spans of a sampled frame, made after the fact from the stamps the pipeline takes anyway
(docs/tracing.md): `netapp.frame` (a server span, the robot's frame span its parent) from receipt to the result
handed to the transport, and its children `decode`, `queue`, `inference` and `deliver`.

A frame whose robot sent a traceparent follows the robot's sampling decision; one without (a 5G-ERA robot) is
sampled by the netapp's own sampler, as a root. Nothing here runs for a frame that is not sampled but the parse.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from netapp import tracecontext
from netapp.server.pipeline.frame import Frame, FrameTrace
from netapp.server.sessions import Session
from netapp.tracing import SpanRecord, Tracer, wall_minus_monotonic_ns

FRAME_SPAN = "netapp.frame"


@dataclass(frozen=True, slots=True)
class FrameStamps:
    """A frame's monotonic stamps (ns); `decoded` (start, end) is (0, 0) when it was not decoded here."""

    recv: int
    decoded: tuple[int, int]
    turn: int
    before: int
    after: int
    end: int


def frame_spans(trace: FrameTrace, stamps: FrameStamps, epoch_ns: int, attributes: dict[str, Any]) -> list[SpanRecord]:
    """The frame's spans, on the Unix clock (`epoch_ns` added to each monotonic stamp). Pure.

    queue: from receipt (or the end of decoding ahead, on the prepare pool) to the start of the frame's batch;
    decode: where it ran (ahead, or on the inference thread at the start of the batch); inference: the batch's
    `process` call; deliver: from its end to the result handed to the transport."""
    s = stamps
    new = tracecontext.new_span_id
    turn = s.turn or s.before
    d0, d1 = s.decoded
    ahead = bool(d1) and d1 <= turn  # decoded on the prepare pool, before it waited for its turn
    queued_from = d1 if ahead else s.recv
    parent = trace.span_id
    spans = [
        SpanRecord(
            FRAME_SPAN,
            trace.span_id,
            trace.parent_id,
            s.recv + epoch_ns,
            s.end + epoch_ns,
            "server",
            attributes,
            remote_parent=bool(trace.parent_id),
        ),
        SpanRecord("queue", new(), parent, queued_from + epoch_ns, max(queued_from, turn) + epoch_ns),
        SpanRecord("inference", new(), parent, s.before + epoch_ns, s.after + epoch_ns),
        SpanRecord("deliver", new(), parent, s.after + epoch_ns, s.end + epoch_ns),
    ]
    if d1:
        spans.insert(1, SpanRecord("decode", new(), parent, d0 + epoch_ns, d1 + epoch_ns))
    return spans


class FrameTracing:
    """The netapp's side of frame tracing over a `Tracer` (the pipeline holds one only when tracing is on)."""

    def __init__(self, tracer: Tracer, ignored: Callable[[], None] = lambda: None) -> None:
        self.tracer = tracer
        self._ignored = ignored  # counts a traceparent that did not parse (ignored: the frame is a root)

    def begin(self, traceparent: Any, tracestate: Any) -> FrameTrace | None:
        """A received frame's trace when it is sampled, else None. The transport's raw fields: parsed only here."""
        parent = tracecontext.parse(traceparent, tracestate) if traceparent is not None else None
        if parent is None and traceparent is not None:
            self._ignored()
        trace_id = parent.trace_id if parent is not None else tracecontext.new_trace_id()
        if not self.tracer.sample(trace_id, parent, FRAME_SPAN):
            return None
        if parent is None:
            return FrameTrace(trace_id, tracecontext.new_span_id())
        return FrameTrace(trace_id, tracecontext.new_span_id(), parent.span_id, parent.tracestate)

    @staticmethod
    def clock_ns() -> int:
        """What a traced result carries (`netapp.protocol.TRACE_CLOCK_FIELD`) and the spans are placed with."""
        return wall_minus_monotonic_ns()

    def finish(self, session: Session, frame: Frame, message: dict[str, Any], end_ns: int, epoch_ns: int) -> None:
        """A traced frame's result went to its transport, stamped `end_ns` (its `send_timestamp`): its spans."""
        trace = frame.trace
        assert trace is not None
        before, after = message.get("timestamp_before_process", 0), message.get("timestamp_after_process", 0)
        stamps = FrameStamps(frame.recv_ns, frame.decoded_ns, frame.turn_ns, before, after, end_ns)
        spans = frame_spans(trace, stamps, epoch_ns, self._attributes(session, frame))
        self.tracer.emit(trace.trace_id, spans, trace.tracestate)

    def failed(self, session: Session, frame: Frame, reason: str, end_ns: int) -> None:
        """A traced frame answered with an error (late, superseded, refused by its processor): one span, why."""
        trace = frame.trace
        assert trace is not None
        epoch = wall_minus_monotonic_ns()
        span = SpanRecord(
            FRAME_SPAN,
            trace.span_id,
            trace.parent_id,
            frame.recv_ns + epoch,
            end_ns + epoch,
            "server",
            self._attributes(session, frame),
            error=reason,
            remote_parent=bool(trace.parent_id),
        )
        self.tracer.emit(trace.trace_id, [span], trace.tracestate)

    @staticmethod
    def _attributes(session: Session, frame: Frame) -> dict[str, Any]:
        timestamp = frame.timestamp  # any integer on Socket.IO: an attribute holds 64 bits
        attributes: dict[str, Any] = {
            "netapp.transport": frame.transport,
            "netapp.session.id": session.id[:64],
            "netapp.frame.timestamp": timestamp if -(2**63) <= timestamp < 2**63 else str(timestamp),
        }
        if session.robot_id:
            attributes["netapp.robot.id"] = str(session.robot_id)[:128]
        return attributes
