from __future__ import annotations

from fastapi import APIRouter

from ..dependencies import ServicesDep

router = APIRouter(tags=["health"])


@router.get("/healthz")
def healthz(services: ServicesDep) -> dict[str, str]:
    """Liveness and readiness (no token needed)."""
    return {"status": "ok", "backend": services.registry.backend.name}
