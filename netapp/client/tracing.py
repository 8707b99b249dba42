"""The robot's side of frame tracing (docs/tracing.md): each frame starts a trace whose root span, `frame`, runs from
the frame's hand-over to the transport to its result handed to the robot; its children `send` (encoding and putting
it on the wire) and `receive` (the result's delivery), and the netapps' `netapp.frame` spans, whose parent it is.

The sampling decision is the robot's (its sampler, as a root); every frame, sampled or not, carries its traceparent,
so the netapps follow it. The spans are made when the answer comes, with the netapp's clock: the robot's monotonic
stamps are moved onto the netapp's timeline by the clock offset the link estimates (`netapp.client.timing`), so
robot and netapp spans line up.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

from netapp import tracecontext
from netapp.client.timing import server_stamps, span_offset
from netapp.protocol import TRACE_CLOCK_FIELD
from netapp.tracing import SpanRecord, Tracer, wall_minus_monotonic_ns

SERVICE_NAME = "netapp-robot"  # the robot's traces' service.name unless OTEL_SERVICE_NAME says otherwise
ROOT_SPAN = "frame"
FRAMES_KEPT = 256  # frames in flight whose trace is remembered (more than any in-flight bound)


@dataclass
class _Traced:
    context: tracecontext.TraceContext  # the root span's: what the netapps get as their parent
    sent_ns: int  # monotonic, when the frame was handed over (t1)
    wire_ns: int = 0  # when it was on the wire to every netapp


class FrameTraces:
    """Each frame's trace from `begin` to `received` (or `failed`); frames never answered fall off the end."""

    def __init__(self, tracer: Tracer, transport: str) -> None:
        self.tracer = tracer
        self._transport = transport
        self._lock = threading.Lock()
        self._frames: OrderedDict[int, _Traced] = OrderedDict()  # by frame timestamp

    def begin(self, timestamp: int, sent_ns: int) -> dict[str, str]:
        """A frame goes out: its trace context, as the transports carry it (`TraceContext.fields`)."""
        trace_id = tracecontext.new_trace_id()
        sampled = self.tracer.sample(trace_id, None, ROOT_SPAN)
        context = tracecontext.TraceContext(trace_id, tracecontext.new_span_id(), sampled)
        if sampled:
            with self._lock:
                self._frames[timestamp] = _Traced(context, sent_ns)
                while len(self._frames) > FRAMES_KEPT:
                    self._frames.popitem(last=False)
        return context.fields()

    def on_wire(self, timestamp: int, now_ns: int) -> None:
        with self._lock:
            traced = self._frames.get(timestamp)
            if traced is not None:
                traced.wire_ns = now_ns

    def received(
        self, timestamp: Any, received_ns: int, message: dict[str, Any], offset_ns: int | None, url: str
    ) -> None:
        """The first answer to a sampled frame was handed to the robot: its spans. `received_ns` is when it arrived;
        `offset_ns` the link's netapp-minus-robot clock estimate (None: none yet)."""
        traced = self._take(timestamp)
        if traced is None:
            return
        done = time.monotonic_ns()
        epoch = _robot_epoch(traced.sent_ns, received_ns, message, offset_ns)
        root = traced.context.span_id
        new = tracecontext.new_span_id
        wire = min(traced.wire_ns or received_ns, received_ns)
        spans = [
            SpanRecord(ROOT_SPAN, root, 0, traced.sent_ns + epoch, done + epoch, "client", self._attributes(url)),
            SpanRecord("send", new(), root, traced.sent_ns + epoch, max(traced.sent_ns, wire) + epoch),
            SpanRecord("receive", new(), root, received_ns + epoch, done + epoch),
        ]
        self.tracer.emit(traced.context.trace_id, spans)

    def failed(self, timestamp: Any, now_ns: int, reason: str, url: str) -> None:
        """A netapp answered a sampled frame with an error: the root span, ended then, says why."""
        traced = self._take(timestamp)
        if traced is None:
            return
        epoch = wall_minus_monotonic_ns()
        span = SpanRecord(
            ROOT_SPAN, traced.context.span_id, 0, traced.sent_ns + epoch, now_ns + epoch, "client",
            self._attributes(url), error=reason or "error",
        )  # fmt: skip
        self.tracer.emit(traced.context.trace_id, [span])

    def _take(self, timestamp: Any) -> _Traced | None:
        with self._lock:
            return self._frames.pop(timestamp, None)  # type: ignore[arg-type]

    def _attributes(self, url: str) -> dict[str, Any]:
        return {"netapp.url": url, "netapp.transport": self._transport}


class RootSpan:
    """A robot's own root span around a request (the middleware's `deploy`): its trace context goes in the
    request's headers, the span when it ends. Not sampled: the context still goes (the far side follows it)."""

    def __init__(self, tracer: Tracer, name: str, attributes: dict[str, Any]) -> None:
        trace_id = tracecontext.new_trace_id()
        self.context = tracecontext.TraceContext(
            trace_id, tracecontext.new_span_id(), tracer.sample(trace_id, None, name)
        )
        self._tracer, self._name, self._attributes = tracer, name, attributes
        self._start_ns = time.time_ns()

    def end(self, error: str | None = None) -> None:
        if self.context.sampled:
            span = SpanRecord(
                self._name, self.context.span_id, 0, self._start_ns, time.time_ns(), "client", self._attributes, error
            )
            self._tracer.emit(self.context.trace_id, [span])


def _robot_epoch(t1: int, t4: int, message: dict[str, Any], offset_ns: int | None) -> int:
    """What to add to the robot's monotonic stamps of this frame to place them on the netapp's Unix timeline: the
    clock offset (kept within what this frame's own stamps allow, so the robot's spans enclose the netapp's) plus
    the netapp's wall-minus-monotonic clock from its result. Without both: the robot's own Unix clock."""
    clock = message.get(TRACE_CLOCK_FIELD)
    stamps = server_stamps(message)
    if offset_ns is None or stamps is None or not isinstance(clock, int) or isinstance(clock, bool):
        return wall_minus_monotonic_ns()
    return span_offset(offset_ns, t1, stamps[0], stamps[3], t4) + clock
