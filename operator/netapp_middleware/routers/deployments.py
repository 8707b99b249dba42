from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Query, Response
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field

from netapp.http_errors import HTTPError

from ..dependencies import RobotDep, ServicesDep
from ..deployments import NotFound, QuotaExceeded

router = APIRouter(prefix="/deployments", tags=["deployments"])

# edge, cloud, auto, or a node pool's (DNS-1123 label) name.
PLACEMENT_PATTERN = r"^[a-z0-9]([-a-z0-9]{0,61}[a-z0-9])?$"


class DeploymentRequest(BaseModel):
    app: str = Field(min_length=1, max_length=253)
    placement: str | None = Field(
        default=None, pattern=PLACEMENT_PATTERN, description="edge, cloud, auto, or a node pool name"
    )
    reuse: bool = Field(
        default=True, description="share a NetApp with other robots asking for the same app and placement"
    )


@router.post("", status_code=202)
async def create(body: DeploymentRequest, services: ServicesDep, robot_id: RobotDep) -> dict[str, Any]:
    app = (await run_in_threadpool(services.catalogue)).get(body.app)
    if app is None:
        raise HTTPError(404, "not_found", f"no app {body.app!r} in the catalogue: GET /apps lists them")
    try:
        return services.registry.create(robot_id, app, body.placement, body.reuse).view()
    except QuotaExceeded as exc:
        raise HTTPError(429, "too_many_requests", str(exc)) from exc


@router.get("")
async def list_deployments(services: ServicesDep, robot_id: RobotDep) -> dict[str, Any]:
    return {"deployments": [d.view() for d in services.registry.list(robot_id)]}


@router.get("/{deployment_id}")
async def get(
    deployment_id: str,
    services: ServicesDep,
    robot_id: RobotDep,
    wait: float = Query(
        0.0, ge=0.0, description="long-poll: return as soon as the deployment changes, or after this many seconds"
    ),
    since: int | None = Query(None, description="the `version` the robot last saw (default: the current one)"),
) -> dict[str, Any]:
    try:
        if wait > 0:
            deployment = await services.registry.wait(robot_id, deployment_id, since, min(wait, services.max_wait_s))
        else:
            deployment = services.registry.get(robot_id, deployment_id)
    except NotFound as exc:
        raise HTTPError(404, "not_found", "no such deployment") from exc
    return deployment.view()


@router.delete("/{deployment_id}", status_code=204)
async def delete(deployment_id: str, services: ServicesDep, robot_id: RobotDep) -> Response:
    try:
        await services.registry.delete(robot_id, deployment_id)
    except NotFound as exc:
        raise HTTPError(404, "not_found", "no such deployment") from exc
    return Response(status_code=204)
