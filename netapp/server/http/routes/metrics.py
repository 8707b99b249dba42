"""What this replica measures: Prometheus metrics (GET /metrics) and its capacity (GET /capacity)."""

from __future__ import annotations

from dataclasses import asdict

from fastapi import APIRouter
from fastapi.responses import Response
from prometheus_client import CONTENT_TYPE_LATEST

from netapp.server.cluster.heartbeat import heartbeat_body
from netapp.server.http.dependencies import Services
from netapp.server.http.schemas import Capacity

router = APIRouter()


@router.get("/capacity")
async def capacity(services: Services) -> Capacity:
    """What this replica can serve, as measured: the 5G-ERA heartbeat's fields and the figures behind them."""
    return Capacity(**heartbeat_body(services), **asdict(services.capacity()))


@router.get("/metrics")
async def metrics(services: Services) -> Response:
    return Response(services.metrics.render(), media_type=CONTENT_TYPE_LATEST)
