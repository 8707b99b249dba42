"""The middleware API on the kubernetes backend against kmock, the test playing the operator (it writes the
NetApps' status): auth, ownership, reuse counting, long-poll waits, failures and a URL change."""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import pytest
import requests
from netapp_middleware.backends.kubernetes import KubernetesBackend
from netapp_operator.constants import ANNOTATION_CLAIMS, GROUP, VERSION

from netapp.client.middleware import DeploymentFailed, Endpoint, MiddlewareClient, MiddlewareError
from tests.middleware.mw_helpers import NS, ROBOTS, Operator, wait_until


def robot(url: str, robot_id: str = "robot-1") -> MiddlewareClient:
    return MiddlewareClient(url, robot_id, ROBOTS[robot_id], long_poll_s=10.0)


def test_health_needs_no_token_and_everything_else_does(cluster: tuple[str, Operator]) -> None:
    url, _ = cluster
    assert requests.get(f"{url}/healthz", timeout=10).json() == {"status": "ok", "backend": "kubernetes"}
    for method, path in (
        ("GET", "/apps"),
        ("POST", "/deployments"),
        ("GET", "/deployments/x"),
        ("DELETE", "/deployments/x"),
        ("POST", "/auth/refresh"),
        ("POST", "/Task/Plan"),
        ("GET", "/orchestrate/orchestrate/plan/x"),
    ):
        for headers in ({}, {"Authorization": "Bearer not-a-token"}, {"Authorization": "Basic cm9ib3Q6eA=="}):
            response = requests.request(method, f"{url}{path}", headers=headers, json={}, timeout=10)
            assert response.status_code == 401, (method, path, headers, response.text)
    bad = requests.post(f"{url}/auth/token", json={"robot_id": "robot-1", "secret": "wrong"}, timeout=10)
    assert bad.status_code == 401
    unknown = requests.post(f"{url}/auth/token", json={"robot_id": "robot-9", "secret": "x"}, timeout=10)
    assert unknown.status_code == 401
    with pytest.raises(MiddlewareError, match="401"):
        MiddlewareClient(url, "robot-1", "wrong").apps()


def test_token_refresh_and_expiry(kube_api: Any, start_middleware: Any) -> None:
    server = start_middleware(KubernetesBackend(NS, kube_api.new_kube()), token_ttl_s=2.0)
    login = requests.post(
        f"{server.url}/auth/token", json={"robot_id": "robot-1", "secret": ROBOTS["robot-1"]}, timeout=10
    ).json()
    auth = {"Authorization": f"Bearer {login['access_token']}"}
    assert requests.get(f"{server.url}/apps", headers=auth, timeout=10).status_code == 200
    refreshed = requests.post(f"{server.url}/auth/refresh", headers=auth, timeout=10).json()
    assert refreshed["robot_id"] == "robot-1" and refreshed["expires_at"] >= login["expires_at"]
    wait_until(lambda: time.time() > login["expires_at"] + 0.1, what="the token to expire")
    expired = requests.get(f"{server.url}/apps", headers=auth, timeout=10)
    assert expired.status_code == 401 and "expired" in expired.json()["error"]
    # The robot client logs in again by itself.
    assert "object-detection" in robot(server.url).apps()


def test_deploy_follow_and_delete(cluster: tuple[str, Operator]) -> None:
    url, operator = cluster
    progress: list[str] = []
    result: dict[str, Any] = {}
    mw = robot(url)

    def deploy() -> None:
        try:
            result["endpoint"] = mw.deploy(
                "object-detection",
                placement="edge",
                timeout=60,
                on_progress=lambda view: progress.append(view["status"]),
            )
        except Exception as exc:  # surfaced by the assertions below
            result["error"] = exc

    thread = threading.Thread(target=deploy)
    thread.start()
    netapp = operator.the_one()
    assert netapp["spec"]["placement"] == {"policy": "edge"}
    assert netapp["spec"]["image"] and netapp["metadata"]["labels"]["netapp.dev/app"] == "object-detection"
    name = netapp["metadata"]["name"]
    operator.set_status(name, "Deploying", pool="edge-1")
    wait_until(lambda: "Deploying" in progress, what="the robot to see Deploying")
    operator.set_status(name, "Ready", url="http://10.0.0.7:5896", pool="edge-1")
    thread.join(60)
    assert "error" not in result, result
    endpoint = result["endpoint"]
    assert endpoint.url == "http://10.0.0.7:5896" and endpoint.pool == "edge-1"
    assert progress[0] == "Pending" and progress[-1] == "Ready"

    # A failover: the operator moves the NetApp; the robot's follower reports the new URL once it is Ready.
    moved: list[Endpoint] = []
    changed = threading.Event()
    mw.follow(endpoint, lambda new: (moved.append(new), changed.set()))
    operator.set_status(name, "Deploying", url="http://10.0.9.9:5896", pool="cloud-1")
    operator.set_status(name, "Ready", url="http://10.0.9.9:5896", pool="cloud-1")
    assert changed.wait(30), "the follower did not report the new URL"
    assert moved == [
        Endpoint(
            endpoint.deployment_id,
            "object-detection",
            "http://10.0.9.9:5896",
            "cloud-1",
            urls=("http://10.0.9.9:5896",),
            tokens=(None,),
        )
    ]

    mw.delete(endpoint)
    wait_until(lambda: not operator.netapps(), what="the NetApp to be deleted")
    with pytest.raises(MiddlewareError, match="404"):
        mw.status(endpoint)


def test_robots_see_and_delete_only_their_own(cluster: tuple[str, Operator]) -> None:
    url, operator = cluster
    one, two = robot(url, "robot-1"), robot(url, "robot-2")
    view = one.create("object-detection", reuse=False)
    for call in (lambda: two.status(view["id"]), lambda: two.status(view["id"], wait=1)):
        with pytest.raises(MiddlewareError) as info:
            call()
        assert info.value.status == 404
    for path in (f"/deployments/{view['id']}", f"/orchestrate/orchestrate/plan/{view['id']}"):
        assert requests.delete(f"{url}{path}", headers=two._auth_header(), timeout=10).status_code == 404
    assert one.status(view["id"])["id"] == view["id"]
    listing = requests.get(f"{url}/deployments", timeout=10, headers=two._auth_header()).json()
    assert listing == {"deployments": []}
    assert len(operator.netapps()) == 1
    one.close()
    wait_until(lambda: not operator.netapps(), what="the NetApp to be deleted")


def test_reuse_shares_one_netapp_until_the_last_robot_leaves(cluster: tuple[str, Operator]) -> None:
    url, operator = cluster
    one, two = robot(url, "robot-1"), robot(url, "robot-2")
    a = one.create("object-detection", placement="cloud")
    b = two.create("object-detection", placement="cloud")
    assert a["netapp"] == b["netapp"] and b["robots"] == 2
    alone = two.create("object-detection", placement="cloud", reuse=False)
    elsewhere = two.create("object-detection", placement="edge")
    assert len({a["netapp"], alone["netapp"], elsewhere["netapp"]}) == 3
    assert set(wait_until(lambda: len(operator.netapps()) == 3 and operator.netapps())) == {
        a["netapp"],
        alone["netapp"],
        elsewhere["netapp"],
    }
    for view in (alone, elsewhere):
        two.delete(view["id"])
    one.delete(a["id"])
    assert set(operator.netapps()) == {a["netapp"]}  # robot-2 still uses it
    assert two.status(b["id"])["robots"] == 1
    two.delete(b["id"])
    assert operator.netapps() == {}


def test_long_poll_returns_on_change(cluster: tuple[str, Operator]) -> None:
    url, operator = cluster
    mw = robot(url)
    view = mw.create("object-detection")
    # Settle first: the watch's first report of the new NetApp is a change too.
    view = wait_until(lambda: (v := mw.status(view["id"]))["message"] == "waiting for the operator" and v)
    timer = threading.Timer(0.5, operator.set_status, (view["netapp"], "Deploying"))
    started = time.monotonic()
    timer.start()
    changed = mw.status(view["id"], wait=20, since=view["version"])
    took = time.monotonic() - started
    assert changed["status"] == "Deploying" and changed["version"] > view["version"]
    assert took < 10, f"the long poll took {took:.1f} s"
    # A robot that already saw the latest version waits until the timeout.
    started = time.monotonic()
    same = mw.status(view["id"], wait=1, since=changed["version"])
    assert same["version"] == changed["version"] and time.monotonic() - started >= 0.9
    mw.close()


def test_failure_is_reported_with_the_operators_reason(cluster: tuple[str, Operator]) -> None:
    url, operator = cluster
    mw = robot(url)
    failures: list[BaseException] = []
    thread = threading.Thread(target=lambda: _expect(failures, lambda: mw.deploy("object-detection", timeout=60)))
    thread.start()
    operator.set_status(operator.the_one()["metadata"]["name"], "Failed")
    thread.join(60)
    assert len(failures) == 1 and isinstance(failures[0], DeploymentFailed)
    assert "test says Failed" in str(failures[0])
    with pytest.raises(MiddlewareError, match="404"):
        mw.create("no-such-app")
    mw.close()


def test_a_netapp_deleted_behind_the_middlewares_back_fails_the_deployment(cluster: tuple[str, Operator]) -> None:
    url, operator = cluster
    mw = robot(url)
    view = mw.create("object-detection")
    operator.the_one()
    operator.delete(view["netapp"])
    failed = mw.status(view["id"], wait=20, since=view["version"])
    assert failed["status"] == "Failed" and "deleted outside" in failed["message"]
    mw.close()


def _expect(sink: list[BaseException], call: Any) -> None:
    try:
        call()
    except BaseException as exc:  # noqa: BLE001  collected for the test thread
        sink.append(exc)


def test_a_restarted_middleware_takes_its_netapps_back(kube_api: Any, start_middleware: Any) -> None:
    """Robots' deployments are recorded on their NetApps: a new middleware process (a rolling update) knows them,
    keeps counting a shared one's robots, and deletes a NetApp that no robot uses any more."""
    operator = Operator(kube_api)
    first = start_middleware(KubernetesBackend(NS, kube_api.new_kube()))
    one, two = robot(first.url, "robot-1"), robot(first.url, "robot-2")
    shared_1 = one.create("object-detection", placement="edge")
    shared_2 = two.create("object-detection", placement="edge")
    alone = two.create("object-detection", reuse=False)
    operator.set_status(shared_1["netapp"], "Ready", url="http://10.0.0.7:5896", pool="edge-1")

    def recorded() -> bool:
        claims = {
            n: json.loads(a["metadata"].get("annotations", {}).get(ANNOTATION_CLAIMS, "{}"))
            for n, a in operator.netapps().items()
        }
        return claims.get(shared_1["netapp"], {}).keys() == {shared_1["id"], shared_2["id"]} and bool(
            claims.get(alone["netapp"])
        )

    wait_until(recorded, what="the claims to be recorded on the NetApps")
    # A NetApp of ours whose robots all left while no middleware ran; and someone else's, to be left alone.
    for name, labels in (("orphan", {"app.kubernetes.io/managed-by": "netapp-middleware"}), ("foreign", {})):
        operator.create(
            {
                "apiVersion": f"{GROUP}/{VERSION}",
                "kind": "NetApp",
                "metadata": {"name": name, "namespace": NS, "labels": labels},
                "spec": {"image": "x"},
            },
        )
    first.__exit__(None, None, None)

    second = start_middleware(KubernetesBackend(NS, kube_api.new_kube()))
    one, two = robot(second.url, "robot-1"), robot(second.url, "robot-2")
    wait_until(lambda: "orphan" not in operator.netapps(), what="the unused NetApp to be deleted")
    assert "foreign" in operator.netapps()
    view = one.status(shared_1["id"])
    assert (view["status"], view["url"], view["robots"], view["placement"]) == (
        "Ready",
        "http://10.0.0.7:5896",
        2,
        "edge",
    )
    with pytest.raises(MiddlewareError, match="404"):
        one.status(alone["id"])  # still robot-2's only
    # Reuse goes on with the recovered NetApp; robots leave one by one; the last one deletes it.
    again = one.create("object-detection", placement="edge")
    assert again["netapp"] == shared_1["netapp"] and again["robots"] == 3
    for client, deployment in ((one, shared_1), (one, again), (two, alone)):
        client.delete(deployment["id"])
    assert shared_1["netapp"] in operator.netapps() and alone["netapp"] not in operator.netapps()
    two.delete(shared_2["id"])
    assert set(operator.netapps()) == {"foreign"}


def test_a_robot_cannot_hold_more_than_its_quota(kube_api: Any, start_middleware: Any) -> None:
    server = start_middleware(KubernetesBackend(NS, kube_api.new_kube()), max_per_robot=2)
    one, two = robot(server.url, "robot-1"), robot(server.url, "robot-2")
    first = one.create("object-detection", reuse=False)
    one.create("object-detection", reuse=False)
    with pytest.raises(MiddlewareError) as info:
        one.create("object-detection")
    assert info.value.status == 429
    two.create("object-detection")  # the quota is per robot
    one.delete(first["id"])
    one.create("object-detection")
    for client in (one, two):
        client.close()


def test_reuse_counting_holds_under_concurrent_robots(cluster: tuple[str, Operator]) -> None:
    from concurrent.futures import ThreadPoolExecutor

    url, operator = cluster
    clients = [robot(url, robot_id) for robot_id in ("robot-1", "robot-2") * 4]
    with ThreadPoolExecutor(len(clients)) as pool:
        views = list(pool.map(lambda c: c.create("object-detection", placement="edge"), clients))
        assert len({v["netapp"] for v in views}) == 1
        assert clients[0].status(views[0]["id"])["robots"] == len(clients)
        assert len(wait_until(operator.netapps)) == 1
        list(pool.map(lambda c, v: c.delete(v["id"]), clients, views))
    assert operator.netapps() == {}


def test_a_netapp_deleted_while_no_watch_was_open_fails_the_deployment(kube_api: Any, start_middleware: Any) -> None:
    """The watch starts over with a listing; a NetApp missing from it went while no watch could say so."""
    # A quiet watch ends after its read timeout, as a lost connection would: a short one ends it soon.
    backend = KubernetesBackend(NS, kube_api.new_kube(), watch_read_timeout_s=1.0)
    server = start_middleware(backend)
    operator = Operator(kube_api)
    mw = robot(server.url)
    view = mw.create("object-detection")
    operator.set_status(operator.the_one()["metadata"]["name"], "Ready", url="http://10.0.0.7:5896", pool="edge")
    view = wait_until(lambda: (v := mw.status(view["id"]))["status"] == "Ready" and v)
    kube_api.forget(view["netapp"])
    failed = mw.status(view["id"], wait=30, since=view["version"])
    assert failed["status"] == "Failed" and "deleted outside" in failed["message"]
    mw.close()
