"""The 5G-ERA middleware endpoints that era-5g-client's NetAppClient calls, mapped onto deployments.

Errors use 5G-ERA's shapes: `errors` in a failed login, `statusCode` and `message` in a failed plan request.
"""

from __future__ import annotations

import datetime
from typing import Any

from fastapi import APIRouter, HTTPException, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict

from ..dependencies import RobotDep, ServicesDep, check_login
from ..deployments import NotFound, QuotaExceeded
from ..era import plan_view

router = APIRouter(tags=["5G-ERA"])


class LoginRequest(BaseModel):
    model_config = ConfigDict(extra="allow")
    Id: str
    Password: str


class PlanRequest(BaseModel):
    model_config = ConfigDict(extra="allow")
    TaskId: str
    DisableResourceReuse: bool = False
    RobotId: str | None = None


@router.post("/Login")
def login(body: LoginRequest, services: ServicesDep, request: Request) -> Any:
    try:
        check_login(services, request, body.Id, body.Password)
    except HTTPException as exc:
        return JSONResponse({"errors": [exc.detail]}, status_code=exc.status_code, headers=exc.headers)
    token, claims = services.signer.issue(body.Id, ttl_s=services.era_token_ttl_s)
    expires = datetime.datetime.fromtimestamp(claims.expires_at, tz=datetime.timezone.utc).isoformat()
    return {"token": token, "expirationDate": expires, "id": body.Id}


@router.post("/Task/Plan")
async def plan(body: PlanRequest, services: ServicesDep, robot_id: RobotDep) -> Any:
    app = (await run_in_threadpool(services.catalogue)).by_task_id(body.TaskId)
    if app is None:
        return JSONResponse(
            {"statusCode": 400, "message": f"no app with task id {body.TaskId} in the catalogue"}, status_code=400
        )
    try:
        deployment = services.registry.create(
            robot_id, app, None, not body.DisableResourceReuse, meta={"taskId": body.TaskId, "robotId": body.RobotId}
        )
    except QuotaExceeded as exc:
        return JSONResponse({"statusCode": 400, "message": str(exc)}, status_code=429)
    return {**plan_view(deployment), "ActionPlanId": deployment.id}


@router.get("/orchestrate/orchestrate/plan/{plan_id}")
async def get_plan(plan_id: str, services: ServicesDep, robot_id: RobotDep) -> dict[str, Any]:
    try:
        return plan_view(services.registry.get(robot_id, plan_id))
    except NotFound as exc:
        raise HTTPException(404, "no such action plan") from exc


@router.delete("/orchestrate/orchestrate/plan/{plan_id}")
async def delete_plan(plan_id: str, services: ServicesDep, robot_id: RobotDep) -> Response:
    try:
        await services.registry.delete(robot_id, plan_id)
    except NotFound as exc:
        raise HTTPException(404, "no such action plan") from exc
    return Response(status_code=200)
