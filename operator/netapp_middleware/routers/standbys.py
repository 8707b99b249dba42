from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from ..dependencies import RobotDep, ServicesDep

router = APIRouter(tags=["standbys"])


@router.get("/standbys")
def list_standbys(services: ServicesDep, robot_id: RobotDep) -> dict[str, Any]:
    """The warm netapps waiting for robots, with what they cost (requests; RSS on the local backend)."""
    return services.switchover.following.standbys()
