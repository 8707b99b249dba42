"""An unmodified era-5g-client 1.x robot against the middleware (kubernetes backend on kmock, the test playing
the operator and the kubelet): log in, plan the task, wait for Active, register, stream, follow a switchover,
delete the plan."""

from __future__ import annotations

import datetime
import queue
import threading
import time
from typing import Any

import pytest
import requests
from netapp_middleware.catalogue import OBJECT_DETECTION_TASK_ID

from tests.middleware.mw_helpers import DEADLINE_S, ROBOTS, Operator, era_leave, send_until_result, wait_until

era_client = pytest.importorskip("era_5g_client.client", reason="era-5g-client is installed by `make install`")
from era_5g_client.dataclasses import MiddlewareInfo  # noqa: E402
from era_5g_client.exceptions import FailedToConnect  # noqa: E402

ROBOT_UUID = "3f7f5d8e-6a0b-4c39-9a55-2f0f3c6f3b11"


def era_robot(url: str, secret: str = ROBOTS["robot-1"]) -> Any:
    client = era_client.NetAppClient(callbacks_info={})
    # MiddlewareInfo.address is host:port: the client builds http://{address}/{path} itself.
    client.connect_to_middleware(MiddlewareInfo(url.removeprefix("http://"), "robot-1", secret))
    return client


def test_era_client_plans_waits_for_active_and_deletes(cluster: tuple[str, Operator]) -> None:
    url, operator = cluster
    robot = era_robot(url)
    assert robot.token
    # era-5g-client never refreshes: its token must outlive a working day, not the native API's hour.
    login = requests.post(f"{url}/Login", json={"Id": "robot-1", "Password": ROBOTS["robot-1"]}, timeout=10).json()
    expires = datetime.datetime.fromisoformat(login["expirationDate"])
    assert expires - datetime.datetime.now(datetime.timezone.utc) > datetime.timedelta(hours=23)
    errors: list[BaseException] = []

    def run() -> None:
        try:
            robot.run_task(OBJECT_DETECTION_TASK_ID, ROBOT_UUID, resource_lock=False, mode=era_client.RunTaskMode.WAIT)
        except BaseException as exc:  # noqa: BLE001  checked below
            errors.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    netapp = operator.the_one()
    assert netapp["spec"]["placement"] == {"policy": "auto"}
    assert netapp["metadata"]["labels"]["netapp.dev/shared"] == "true"  # DisableResourceReuse=False
    operator.set_status(netapp["metadata"]["name"], "Deploying", pool="edge-1")
    operator.set_status(netapp["metadata"]["name"], "Ready", url="http://10.1.2.3:5896", pool="edge-1")
    thread.join(30)
    assert not thread.is_alive() and not errors, errors
    assert robot.netapp_address == "http://10.1.2.3:5896"
    assert robot.resource_checker.is_ready()
    robot.resource_checker.stop()
    robot.delete_all_resources()
    assert robot.action_plan_id is None  # the client clears it only on a 2xx answer
    wait_until(lambda: not operator.netapps(), what="the plan's NetApp to be deleted")


def test_era_client_sees_refusals(cluster: tuple[str, Operator]) -> None:
    url, operator = cluster
    with pytest.raises(FailedToConnect):
        era_robot(url, secret="wrong")
    robot = era_robot(url)
    with pytest.raises(FailedToConnect):
        robot.run_task(
            "00000000-0000-4000-8000-000000000000",
            ROBOT_UUID,
            resource_lock=True,
            mode=era_client.RunTaskMode.DO_NOTHING,
        )
    assert operator.netapps() == {}


def test_era_robot_streams_and_follows_a_switchover(cluster: tuple[str, Operator], kubelet: Any, jpeg: bytes) -> None:
    """Log in, plan, wait for Active, register, stream, get results; the NetApp moves to another pool and the
    robot reconnects to the new URL by itself; deleting the plan deletes the NetApp."""
    import cv2
    import numpy as np
    from era_5g_interface.channels import CallbackInfoClient, ChannelType

    url, operator = cluster
    results: queue.Queue[dict[str, Any]] = queue.Queue()
    robot = era_client.NetAppClient(callbacks_info={"results": CallbackInfoClient(ChannelType.JSON, results.put)})
    robot.connect_to_middleware(MiddlewareInfo(url.removeprefix("http://"), "robot-1", ROBOTS["robot-1"]))
    frame = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    send = lambda: robot.send_image(frame, "image", ChannelType.JPEG, time.time_ns())  # noqa: E731
    errors: list[BaseException] = []

    def run() -> None:
        try:
            robot.run_task(OBJECT_DETECTION_TASK_ID, ROBOT_UUID, resource_lock=False, args={"robot": "era"})
        except BaseException as exc:  # noqa: BLE001  checked below
            errors.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        name = operator.the_one()["metadata"]["name"]
        first = kubelet.serve("edge-a")
        operator.set_status(name, "Ready", url=first, pool="edge-1")
        thread.join(DEADLINE_S)
        assert not thread.is_alive() and not errors, errors
        assert robot.netapp_address == first and robot.initialized
        result = send_until_result(send, results)
        assert [d["class_name"] for d in result["detections"]] == ["robot"]

        # The operator moves the NetApp: first Deploying at the new URL (not shown to a 5G-ERA robot), then Ready.
        second = kubelet.serve("cloud-b")
        operator.set_status(name, "Deploying", url=second, pool="cloud-1")
        operator.set_status(name, "Ready", url=second, pool="cloud-1")
        wait_until(
            lambda: robot.netapp_address == second and robot.initialized and not robot.switching,
            what="the robot to switch to the new URL",
        )
        kubelet.stop("edge-a")
        while not results.empty():
            results.get_nowait()
        assert [d["class_name"] for d in send_until_result(send, results)["detections"]] == ["robot"]
    finally:
        era_leave(robot)
    wait_until(lambda: not operator.netapps(), what="the plan's NetApp to be deleted")
