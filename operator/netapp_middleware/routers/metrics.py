"""GET /metrics: Prometheus metrics (no token needed, like /healthz: the chart's ServiceMonitor scrapes it)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import Response
from prometheus_client import CONTENT_TYPE_LATEST

from .. import metrics
from ..dependencies import ServicesDep

router = APIRouter(tags=["health"])


@router.get("/metrics")
def prometheus_metrics(services: ServicesDep) -> Response:
    return Response(metrics.render(services), media_type=CONTENT_TYPE_LATEST)
