"""Scale to zero through the middleware (docs/scaling.md#idle): an app whose spec says `scaling.idleToZero` sleeps
without robots and is woken by a robot asking for it. The local backend stops and starts its netapp process (a robot
that still holds the URL is told to wait at its port and gets results, no error); the kubernetes backend writes the
wake annotation the operator reads, and holds the robot's request (native and 5G-ERA) until the NetApp is Ready."""

from __future__ import annotations

import copy
import queue
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from netapp_middleware.backends.kubernetes import KubernetesBackend
from netapp_middleware.backends.local import LocalBackend
from netapp_middleware.catalogue import DEFAULT_CATALOGUE, OBJECT_DETECTION_TASK_ID
from netapp_operator.constants import ANNOTATION_WAKE

from netapp.client.middleware import MiddlewareClient
from netapp.client.netapp_client import NetAppClient
from tests.middleware.mw_helpers import DEADLINE_S, NS, ROBOTS, Operator, send_until_result, wait_until

IDLE_AFTER = "1s"


def idle_catalogue() -> dict[str, Any]:
    catalogue = copy.deepcopy(DEFAULT_CATALOGUE)
    catalogue["object-detection"]["spec"]["scaling"] = {"idleToZero": IDLE_AFTER}
    return catalogue


def test_local_netapp_sleeps_without_robots_and_wakes_for_a_robot(
    start_middleware: Any, tiny_model_path: Path, jpeg: bytes
) -> None:
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S, idle_poll_s=0.2)
    server = start_middleware(backend, catalogue=idle_catalogue())
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        endpoint = mw.deploy("object-detection", placement="edge", timeout=2 * DEADLINE_S)
        results: queue.Queue[Any] = queue.Queue()
        with NetAppClient(endpoint.url, on_result=results.put) as client:
            assert send_until_result(lambda: client.send(jpeg), results).detections
            time.sleep(1.5)  # a robot connected: never idle, however long it stays
            assert mw.status(endpoint)["status"] == "Ready"
        # The robot left its netapp (it keeps its deployment): the process stops, the URL is kept.
        asleep = wait_until(lambda: _phase(mw, endpoint, "Idle"), what="the netapp asleep")
        assert asleep["url"] == endpoint.url and backend.pids() and not backend.usage(endpoint_name(asleep))

        # Another robot asks for the app: one request, held until the netapp is Ready again, at the same URL.
        with MiddlewareClient(server.url, "robot-2", ROBOTS["robot-2"]) as other:
            started = time.monotonic()
            view = other.create("object-detection", placement="edge", wait=2 * DEADLINE_S)
            assert view["status"] == "Ready" and view["url"] == endpoint.url, view
            assert time.monotonic() - started < DEADLINE_S
        wait_until(lambda: _phase(mw, endpoint, "Idle"), what="asleep again")

        # The first robot comes back to the URL it holds: told to wait while it wakes, then served; no error.
        results = queue.Queue()
        with NetAppClient(endpoint.url, on_result=results.put) as client:
            assert send_until_result(lambda: client.send(jpeg), results).detections
        assert mw.status(endpoint)["status"] == "Ready"


def endpoint_name(view: dict[str, Any]) -> str:
    return str(view["netapp"])


def _phase(mw: MiddlewareClient, endpoint: Any, phase: str) -> dict[str, Any] | None:
    view = mw.status(endpoint)
    return view if view["status"] == phase else None


@pytest.fixture()
def idle_cluster(kube_api: Any, start_middleware: Any) -> tuple[str, Operator]:
    server = start_middleware(KubernetesBackend(NS, kube_api.new_kube()), catalogue=idle_catalogue())
    return server.url, Operator(kube_api)


def wake_of(operator: Operator, name: str) -> str:
    return str((operator.netapps()[name]["metadata"].get("annotations") or {}).get(ANNOTATION_WAKE) or "")


def test_kubernetes_a_robot_asking_wakes_the_netapp_and_gets_its_url_in_one_request(
    idle_cluster: tuple[str, Operator],
) -> None:
    url, operator = idle_cluster
    with MiddlewareClient(url, "robot-1", ROBOTS["robot-1"]) as mw:
        first = mw.create("object-detection", placement="edge")
        name = operator.the_one()["metadata"]["name"]
        operator.set_status(name, "Ready", url="http://10.1.2.3:5896", pool="edge-1")
        wait_until(lambda: mw.status(first["id"])["status"] == "Ready", what="Ready")
        operator.set_status(name, "Idle", url="http://10.1.2.3:5896", pool="edge-1")  # the operator scaled it to 0
        wait_until(lambda: mw.status(first["id"])["status"] == "Idle", what="Idle")
        before = wake_of(operator, name)

        answers: list[dict[str, Any]] = []
        with MiddlewareClient(url, "robot-2", ROBOTS["robot-2"]) as other:
            asking = threading.Thread(
                target=lambda: answers.append(other.create("object-detection", placement="edge", wait=DEADLINE_S))
            )
            asking.start()
            wait_until(lambda: wake_of(operator, name) != before, what="the wake annotation")
            time.sleep(0.3)
            assert asking.is_alive() and not answers  # held: never answered "not ready"
            operator.set_status(name, "Deploying", url="http://10.1.2.3:5896", pool="edge-1")
            operator.set_status(name, "Ready", url="http://10.1.2.3:5896", pool="edge-1")
            asking.join(DEADLINE_S)
            assert answers and answers[0]["status"] == "Ready" and answers[0]["url"] == "http://10.1.2.3:5896"

        # The first robot comes back to the deployment it holds: one request, held until its netapp is Ready.
        operator.set_status(name, "Idle", url="http://10.1.2.3:5896", pool="edge-1")
        wait_until(lambda: mw.status(first["id"])["status"] == "Idle", what="Idle again")
        before = wake_of(operator, name)
        woken: list[Any] = []
        coming_back = threading.Thread(target=lambda: woken.append(mw.wake(first["id"], wait=DEADLINE_S)))
        coming_back.start()
        wait_until(lambda: wake_of(operator, name) != before, what="woken again")
        assert coming_back.is_alive()
        operator.set_status(name, "Ready", url="http://10.1.2.3:5896", pool="edge-1")
        coming_back.join(DEADLINE_S)
        assert woken and woken[0].url == "http://10.1.2.3:5896"


def test_an_unmodified_era_robot_planning_its_task_wakes_the_netapp(idle_cluster: tuple[str, Operator]) -> None:
    era_client = pytest.importorskip("era_5g_client.client", reason="era-5g-client is installed by `make install`")
    from era_5g_client.dataclasses import MiddlewareInfo

    url, operator = idle_cluster
    with MiddlewareClient(url, "robot-2", ROBOTS["robot-2"]) as mw:
        mw.create("object-detection")  # the shared NetApp an era robot's plan claims too (no placement: auto)
        name = operator.the_one()["metadata"]["name"]
        operator.set_status(name, "Idle", url="http://10.1.2.3:5896", pool="edge-1")
        before = wake_of(operator, name)
        robot = era_client.NetAppClient(callbacks_info={})
        robot.connect_to_middleware(MiddlewareInfo(url.removeprefix("http://"), "robot-1", ROBOTS["robot-1"]))
        errors: list[BaseException] = []

        def run() -> None:
            try:
                robot.run_task(
                    OBJECT_DETECTION_TASK_ID,
                    "3f7f5d8e-6a0b-4c39-9a55-2f0f3c6f3b11",
                    resource_lock=False,
                    mode=era_client.RunTaskMode.WAIT,
                )
            except BaseException as exc:  # noqa: BLE001  checked below
                errors.append(exc)

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        wait_until(lambda: wake_of(operator, name) != before, what="the plan to wake the NetApp")
        assert len(operator.netapps()) == 1  # woken, not a second NetApp
        operator.set_status(name, "Ready", url="http://10.1.2.3:5896", pool="edge-1")
        thread.join(DEADLINE_S)
        assert not thread.is_alive() and not errors, errors
        assert robot.netapp_address == "http://10.1.2.3:5896"
        robot.resource_checker.stop()
        robot.delete_all_resources()
