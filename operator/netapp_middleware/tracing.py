"""A deployment's trace (docs/tracing.md): from the robot's `POST /deployments` to the first answer that hands it a
Ready URL, one trace whose root is the middleware's `middleware.deploy` server span (a child of the robot's span
when its request carries a `traceparent`), with the children `netapp.create` (the backend creating the NetApp),
`netapp.ready` (created until Ready) and `url.handed_out` (the request that answered with the URL).

Made after the fact when the URL is handed out, from monotonic stamps the registry keeps on the instance; the
NetApp it creates carries the deploy span's traceparent as an annotation (`ANNOTATION_TRACEPARENT`), so whatever
reconciles it can join the trace.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from netapp import tracecontext
from netapp.tracing import SpanRecord, Tracer, wall_minus_monotonic_ns

from .backends.base import READY

DEPLOY_SPAN = "middleware.deploy"


@dataclass
class DeploymentTrace:
    """A sampled deployment's place in its trace: the deploy span (its id, its parent's), and when it began."""

    trace_id: int
    span_id: int
    parent_id: int
    tracestate: str
    start_ns: int  # monotonic: the POST's arrival
    request_end_ns: int = 0  # the POST's answer

    def traceparent(self) -> str:
        """The deploy span as a parent: what the NetApp's annotation carries."""
        return tracecontext.TraceContext(self.trace_id, self.span_id, True, self.tracestate).traceparent()


class DeploymentTraces:
    """Begins a deployment's trace at its request, and ends it when the URL is handed out."""

    def __init__(self, tracer: Tracer) -> None:
        self.tracer = tracer

    def begin(self, traceparent: str | None, tracestate: str | None, start_ns: int) -> DeploymentTrace | None:
        """A `POST /deployments` arrived at `start_ns`: its trace when sampled (the robot's decision when it sent a
        traceparent, else the middleware's sampler), else None."""
        parent = tracecontext.parse(traceparent, tracestate)
        trace_id = parent.trace_id if parent is not None else tracecontext.new_trace_id()
        if not self.tracer.sample(trace_id, parent, DEPLOY_SPAN):
            return None
        parent_id, state = (parent.span_id, parent.tracestate) if parent is not None else (0, "")
        return DeploymentTrace(trace_id, tracecontext.new_span_id(), parent_id, state, start_ns)

    def handed_out(self, deployment: Any, view: dict[str, Any], request_start_ns: int) -> None:
        """An answer about `deployment` is on its way with `view`: when that first carries a Ready URL, the trace's
        spans go (once)."""
        trace: DeploymentTrace | None = deployment.trace
        if trace is None or view.get("status") != READY or not view.get("url"):
            return
        deployment.trace = None
        end = time.monotonic_ns()
        instance = deployment.instance
        attributes = {"netapp.app": deployment.app, "netapp.robot.id": deployment.robot_id, "netapp.url": view["url"]}
        if deployment.placement:
            attributes["netapp.placement"] = deployment.placement
        if view.get("pool"):
            attributes["netapp.pool"] = view["pool"]
        spans = deploy_spans(trace, instance.stamps if instance.trace is trace else None, request_start_ns, end)
        spans[0].attributes.update(attributes, **{"netapp.name": instance.name})
        self.tracer.emit(trace.trace_id, _on_unix_clock(spans), trace.tracestate)


def deploy_spans(
    trace: DeploymentTrace, stamps: tuple[int, int, int] | None, handout_start_ns: int, end_ns: int
) -> list[SpanRecord]:
    """The deployment's spans on the monotonic clock (pure). `stamps`: the NetApp's (create start, create end,
    Ready) when this deployment created it; None when it reused a running one (no create, no wait)."""
    new = tracecontext.new_span_id
    root = trace.span_id
    spans = [
        SpanRecord(
            DEPLOY_SPAN, root, trace.parent_id, trace.start_ns, end_ns, "server", remote_parent=bool(trace.parent_id)
        )
    ]
    if stamps is not None and all(stamps):
        created, done, ready = stamps
        spans.append(SpanRecord("netapp.create", new(), root, created, done))
        spans.append(SpanRecord("netapp.ready", new(), root, done, max(done, ready)))
    spans.append(SpanRecord("url.handed_out", new(), root, handout_start_ns, end_ns))
    return spans


def _on_unix_clock(spans: list[SpanRecord]) -> list[SpanRecord]:
    epoch = wall_minus_monotonic_ns()
    for span in spans:
        span.start_ns += epoch
        span.end_ns += epoch
    return spans
