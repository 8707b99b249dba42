from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from netapp.http_errors import HTTPError

from ..dependencies import RobotDep, ServicesDep

router = APIRouter(tags=["apps"])


@router.get("/apps")
def list_apps(services: ServicesDep, robot_id: RobotDep) -> dict[str, Any]:
    """The catalogue: app name -> description, 5G-ERA task id and NetApp spec template."""
    return {"apps": {name: app.public() for name, app in services.catalogue().apps.items()}}


@router.get("/apps/{name}/rollouts")
def app_rollouts(name: str, services: ServicesDep, robot_id: RobotDep) -> dict[str, Any]:
    """The rollouts of the app's running NetApps started by a change of its model (docs/rollouts.md)."""
    if services.catalogue().get(name) is None:
        raise HTTPError(404, "not_found", f"no app {name!r} in the catalogue: GET /apps lists them")
    return {"app": name, "rollouts": services.rollouts.of_app(name)}
