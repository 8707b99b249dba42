"""Liveness and readiness (also as the Open Inference Protocol v2's), and the v2 server and model metadata."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from netapp import __version__
from netapp.http_errors import HTTPError
from netapp.server.http.dependencies import Plane
from netapp.server.http.schemas import Health

router = APIRouter()
NOT_READY = {503: {"description": "the model is loading or failed to load, or the replica is draining"}}


@router.get("/healthz")
@router.get("/v2/health/live")
async def live() -> Health:
    return Health(status="live")


@router.get("/readyz", responses=NOT_READY)
@router.get("/v2/health/ready", responses=NOT_READY)
async def ready(plane: Plane) -> Health:
    plane.check_ready()
    return Health(status="ready")


@router.get("/v2")
async def server_metadata(plane: Plane) -> dict:
    """KServe v2 server metadata, plus the one model this netapp serves (so a robot can say what answered it)."""
    models = [plane.model_metadata()]
    return {"name": "netapp-toolkit", "version": __version__, "extensions": [], "models": models}


@router.get("/v2/models/{name}")
async def model_metadata(plane: Plane, name: str) -> dict[str, Any]:
    if name != plane.model_name:
        raise HTTPError(404, "unknown_model", f"unknown model {name!r}; this netapp serves {plane.model_name!r}")
    return plane.model_metadata()


@router.get("/v2/models/{name}/ready")
async def model_ready(plane: Plane, name: str) -> Health:
    if name != plane.model_name:
        raise HTTPError(404, "unknown_model", f"unknown model {name!r}")
    return await ready(plane)
