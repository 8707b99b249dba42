"""The 5G-ERA plan of a NetApp that needs a token carries it (`serviceToken`, beside 5G-ERA's keys), the same one
the native deployment view gives; an unmodified era-5g-client ignores the key."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import requests
from netapp_middleware.backends.local import LocalBackend
from netapp_middleware.catalogue import OBJECT_DETECTION_TASK_ID

from netapp.client.middleware import MiddlewareClient
from tests.middleware.mw_helpers import DEADLINE_S, ROBOTS, wait_until

GUARDED = {"guarded": {"spec": {"image": "x"}, "taskId": OBJECT_DETECTION_TASK_ID, "allowUnauthenticated": False}}


def era_plan(url: str, robot: str) -> dict[str, Any]:
    """The 5G-ERA flow over plain HTTP: log in, plan the task, poll the plan until Active; its service entry."""
    login = requests.post(f"{url}/Login", json={"Id": robot, "Password": ROBOTS[robot]}, timeout=10).json()
    headers = {"Authorization": f"Bearer {login['token']}"}
    plan = requests.post(f"{url}/Task/Plan", json={"TaskId": OBJECT_DETECTION_TASK_ID}, headers=headers, timeout=10)
    plan_id = plan.json()["ActionPlanId"]

    def active() -> dict[str, Any] | None:
        view = requests.get(f"{url}/orchestrate/orchestrate/plan/{plan_id}", headers=headers, timeout=10).json()
        service = view["actionSequence"][0]["Services"][0]
        return service if service["serviceStatus"] == "Active" else None

    return wait_until(active, timeout=2 * DEADLINE_S, what="the plan to be Active")


def test_the_5g_era_plan_carries_the_netapp_token(start_middleware: Any, tiny_model_path: Path) -> None:
    server = start_middleware(LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S), GUARDED)
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        endpoint = mw.deploy("guarded", timeout=2 * DEADLINE_S)
        assert endpoint.token and endpoint.token not in repr(endpoint)  # never in a log line
        service = era_plan(server.url, "robot-2")  # shares the instance, so its token
        assert service["serviceUrl"] == endpoint.url and service["serviceToken"] == endpoint.token
        with_token = {"Authorization": f"Bearer {service['serviceToken']}"}
        assert requests.post(f"{endpoint.url}/register", json={}, headers=with_token, timeout=5).status_code == 201
