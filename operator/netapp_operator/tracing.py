"""The operator's span in a deployment's trace (docs/tracing.md): a NetApp the middleware created carries the
deploy span's traceparent (`ANNOTATION_TRACEPARENT`); each reconcile of it that changed something (applied its
children or wrote its status) is an `operator.reconcile` span under that span. Made after the fact, off unless
configured, like every span here (`netapp.tracing`)."""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from netapp import tracecontext
from netapp.tracing import SpanRecord, Tracer
from netapp_operator.constants import ANNOTATION_TRACEPARENT

SERVICE_NAME = "netapp-operator"  # its traces' service.name unless OTEL_SERVICE_NAME says otherwise
RECONCILE_SPAN = "operator.reconcile"


def reconcile_span(
    netapp: Mapping[str, Any], start_ns: int, end_ns: int, attributes: dict[str, Any]
) -> tuple[tracecontext.TraceContext, SpanRecord] | None:
    """The span of one reconcile of `netapp` (Unix ns), under its annotation's span; None without a valid one or
    when that span was not sampled. Pure."""
    annotations = (netapp.get("metadata") or {}).get("annotations") or {}
    parent = tracecontext.parse(annotations.get(ANNOTATION_TRACEPARENT))
    if parent is None or not parent.sampled:
        return None
    span = SpanRecord(
        RECONCILE_SPAN, tracecontext.new_span_id(), parent.span_id, start_ns, end_ns, attributes=attributes,
        remote_parent=True,
    )  # fmt: skip
    return parent, span


def emit_reconcile(tracer: Tracer | None, netapp: Mapping[str, Any], start_ns: int, attributes: dict[str, Any]) -> None:
    """Export the span of a reconcile that began at `start_ns` (Unix) and ends now, if the NetApp is traced."""
    if tracer is None:
        return
    made = reconcile_span(netapp, start_ns, time.time_ns(), attributes)
    if made is not None:
        parent, span = made
        tracer.emit(parent.trace_id, [span], parent.tracestate)
