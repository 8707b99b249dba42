"""A NetApp that requires a token: the middleware hands the token to the robot with the URL (its deployment view
and the 5G-ERA plan), read from the NetApp's Secret (kubernetes backend) or made with the process (local backend),
and `MiddlewareClient.netapp_client` passes it on without the robot doing anything."""

from __future__ import annotations

import copy
import queue
from pathlib import Path
from typing import Any

import pytest
import requests
from mw_helpers import DEADLINE_S, NS, ROBOTS, Operator, send_until_result, wait_until
from netapp_middleware.backends.local import LocalBackend
from netapp_middleware.catalogue import DEFAULT_CATALOGUE, OBJECT_DETECTION_TASK_ID
from netapp_operator.render import render_token_secret

from netapp.client import NetAppClient, NetAppError
from netapp.client.middleware import MiddlewareClient


def catalogue(require_token: bool) -> dict[str, Any]:
    apps = copy.deepcopy(DEFAULT_CATALOGUE)
    apps["object-detection"]["spec"]["access"] = {"requireToken": require_token}
    return apps


def era_plan(url: str, robot: str = "robot-1") -> dict[str, Any]:
    """The 5G-ERA flow over plain HTTP: log in, plan the task, poll the plan until Active."""
    login = requests.post(f"{url}/Login", json={"Id": robot, "Password": ROBOTS[robot]}, timeout=10).json()
    headers = {"Authorization": f"Bearer {login['token']}"}
    plan = requests.post(f"{url}/Task/Plan", json={"TaskId": OBJECT_DETECTION_TASK_ID}, headers=headers, timeout=10)
    plan_id = plan.json()["ActionPlanId"]

    def active() -> dict[str, Any] | None:
        view = requests.get(f"{url}/orchestrate/orchestrate/plan/{plan_id}", headers=headers, timeout=10).json()
        service = view["actionSequence"][0]["Services"][0]
        return service if service["serviceStatus"] == "Active" else None

    return wait_until(active, timeout=2 * DEADLINE_S, what="the plan to be Active")


def test_local_robot_gets_the_token_and_uses_it_transparently(
    start_middleware: Any, tiny_model_path: Path, jpeg: bytes
) -> None:
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S)
    server = start_middleware(backend, catalogue=catalogue(require_token=True))
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        endpoint = mw.deploy("object-detection", timeout=2 * DEADLINE_S)
        assert endpoint.token and len(endpoint.token) >= 32
        assert endpoint.token not in repr(endpoint)  # never in a log line
        # The netapp refuses anyone without it...
        refused = requests.post(f"{endpoint.url}/register", json={}, timeout=5)
        assert refused.status_code == 401 and refused.json()["reason"] == "unauthorized"
        with pytest.raises(NetAppError, match="unauthorized"):
            NetAppClient(endpoint.url, transport="ws").connect()
        # ...and the robot that asked the middleware streams without handling the token itself.
        for transport in ("ws", "http"):
            results: queue.Queue[Any] = queue.Queue()
            with mw.netapp_client(endpoint, transport=transport, on_result=results.put) as client:
                result = send_until_result(lambda c=client: c.send(jpeg), results)
            assert [d["class_name"] for d in result.detections] == ["robot"]
        # The 5G-ERA plan carries it too (a robot of another owner shares the instance, and its token).
        service = era_plan(server.url, "robot-2")
        assert service["serviceUrl"] == endpoint.url and service["serviceToken"] == endpoint.token


def test_local_netapp_that_does_not_require_a_token_is_open(start_middleware: Any, tiny_model_path: Path) -> None:
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S)
    server = start_middleware(backend, catalogue=catalogue(require_token=False))
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        endpoint = mw.deploy("object-detection", timeout=2 * DEADLINE_S)
        assert endpoint.token is None
        assert requests.post(f"{endpoint.url}/register", json={}, timeout=5).status_code == 201


def test_kubernetes_backend_reads_the_token_from_the_netapps_secret(cluster: tuple[str, Operator]) -> None:
    url, operator = cluster
    with MiddlewareClient(url, "robot-1", ROBOTS["robot-1"]) as mw:
        view = mw.create("object-detection")
        netapp = operator.the_one()
        name = netapp["metadata"]["name"]
        # Like the operator: the Secret first, then the status with the URL.
        secure = copy.deepcopy(netapp)
        secure["spec"]["access"] = {"requireToken": True}
        operator.cluster.run(operator.cluster.kube.apply(secure))
        operator.cluster.run(operator.cluster.kube.create(render_token_secret(netapp, "the-netapps-token")))
        operator.set_status(name, "Ready", url="http://10.1.2.3:5896", pool="edge-1")

        def ready() -> dict[str, Any] | None:
            current = mw.status(view["id"])
            return current if current["status"] == "Ready" and current["token"] else None

        ready_view = wait_until(ready, what="a Ready view with the token")
        assert ready_view["token"] == "the-netapps-token" and ready_view["url"] == "http://10.1.2.3:5896"
        assert operator.cluster.run(operator.cluster.kube.get("Secret", NS, f"{name}-token"))  # read, not moved


def test_kubernetes_backend_hands_no_token_for_an_open_netapp(cluster: tuple[str, Operator]) -> None:
    url, operator = cluster
    with MiddlewareClient(url, "robot-1", ROBOTS["robot-1"]) as mw:
        view = mw.create("object-detection")
        netapp = operator.the_one()
        operator.cluster.run(operator.cluster.kube.create(render_token_secret(netapp, "unused")))
        operator.set_status(netapp["metadata"]["name"], "Ready", url="http://10.1.2.3:5896", pool="edge-1")
        current = wait_until(lambda: (v := mw.status(view["id"]))["status"] == "Ready" and v, what="Ready")
        assert current["token"] is None
