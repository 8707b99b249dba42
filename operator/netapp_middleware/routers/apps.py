from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from ..dependencies import RobotDep, ServicesDep

router = APIRouter(tags=["apps"])


@router.get("/apps")
def list_apps(services: ServicesDep, robot_id: RobotDep) -> dict[str, Any]:
    """The catalogue: app name -> description, 5G-ERA task id and NetApp spec template."""
    return {"apps": {name: app.public() for name, app in services.catalogue().apps.items()}}
