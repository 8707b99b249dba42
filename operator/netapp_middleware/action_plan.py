"""A deployment as a 5G-ERA action plan (what era-5g-client's MiddlewareResourceChecker parses)."""

from __future__ import annotations

from typing import Any

from .backends.base import DEPLOYING, FAILED, IDLE, PENDING, READY
from .deployments import Deployment

# Idle: asked for, so being woken (the robot waits for Active as for a new one)
SERVICE_STATUS = {
    PENDING: "Instantiating",
    DEPLOYING: "Instantiating",
    IDLE: "Instantiating",
    READY: "Active",
    FAILED: "Problem",
}


def service_status(phase: str) -> str:
    return SERVICE_STATUS.get(phase, "Idle")


def plan_view(deployment: Deployment) -> dict[str, Any]:
    """The action plan; `actionSequence[0].Services[0]` carries `serviceStatus` and `serviceUrl`.

    era-5g-client reconnects as soon as it sees a new `serviceUrl`, then waits for `Active` inside the polling
    thread itself, which stops polling: a new URL shown before it is Active would hang that robot forever. So the
    URL shown is the one last seen Ready, and a failover's new URL appears together with `Active`.
    """
    instance = deployment.instance
    status = service_status(instance.state.phase)
    url = instance.state.url if status == "Active" else instance.last_ready_url
    service = {
        "Id": instance.name,
        "Name": deployment.app,
        "ServiceInstanceId": instance.name,
        "serviceStatus": status,
        "serviceUrl": url or "",
        # Ours, beside 5G-ERA's keys: the bearer token of a NetApp that requires one (unmodified clients ignore it),
        # and, for an app whose channel is a broker, the broker URL that names the NetApp (docs/broker.md).
        "serviceToken": instance.token or "",
        "serviceBroker": (deployment.address(instance) or "") if deployment.meta.get("channel") else "",
        "Location": instance.state.pool or "",
        "Message": instance.state.message,
    }
    return {
        "ActionPlanId": deployment.id,
        "TaskId": deployment.meta.get("taskId"),
        "RobotId": deployment.meta.get("robotId"),
        "Status": status,
        "actionSequence": [{"Name": deployment.app, "Order": 0, "Services": [service]}],
    }
