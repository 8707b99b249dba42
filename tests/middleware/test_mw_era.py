"""An unmodified era-5g-client 1.x robot against the middleware (kubernetes backend on kmock, the test playing
the operator): log in, plan the task, wait for Active, read the URL, delete the plan."""

from __future__ import annotations

import threading
from typing import Any

import pytest
from mw_helpers import ROBOTS, Operator, wait_until

from netapp_middleware.catalogue import OBJECT_DETECTION_TASK_ID

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
    errors: list[BaseException] = []

    def run() -> None:
        try:
            robot.run_task(OBJECT_DETECTION_TASK_ID, ROBOT_UUID, resource_lock=False,
                           mode=era_client.RunTaskMode.WAIT)
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
        robot.run_task("00000000-0000-4000-8000-000000000000", ROBOT_UUID, resource_lock=True,
                       mode=era_client.RunTaskMode.DO_NOTHING)
    assert operator.netapps() == {}
