"""Following a robot, end to end on the local backend (real netapp processes on loopback): a warm standby waits on
the robots' next-best placement, shared, and goes when no robot needs it; a route's pool is readied ahead, the robot
moved there on time and what it left behind released; the move, make before break, loses no frame and takes the
tracker's state along; bad routes are refused with one line each."""

from __future__ import annotations

import queue
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import requests
from netapp_middleware.backends.local import LocalBackend
from netapp_middleware.catalogue import DEFAULT_CATALOGUE
from netapp_middleware.switchover.ahead import AheadPolicy

from netapp.client.middleware import MiddlewareClient, MiddlewareError
from tests.middleware.mw_helpers import DEADLINE_S, ROBOTS, send_until_result, wait_until

QUICK = AheadPolicy(min_dwell_s=0.0, warm_lead_s=600, switch_lead_s=0.2, idle_grace_s=0.3, min_route_interval_s=0)


def follow(policy: AheadPolicy = QUICK) -> dict[str, Any]:
    return {"ahead": policy, "tick_s": 0.05, "drain_s": 1.0}


def with_standby(app: str = "object-detection") -> dict[str, Any]:
    return {app: {**DEFAULT_CATALOGUE[app], "standby": "nextBest"}}


def ready_standbys(mw: MiddlewareClient, count: int = 1) -> list[dict[str, Any]]:
    rows = mw.standbys()["standbys"]
    return rows if len(rows) == count and all(r["phase"] == "Ready" for r in rows) else []


def test_a_warm_standby_waits_on_the_next_best_placement_shared_and_released(
    start_middleware: Any, tiny_model_path: Path
) -> None:
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S)
    server = start_middleware(backend, catalogue=with_standby(), switchover=follow())
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        assert mw.standbys()["standbys"] == []  # no robot, no standby
        edge = mw.deploy("object-detection", placement="edge", timeout=2 * DEADLINE_S)
        (standby,) = wait_until(lambda: ready_standbys(mw), what="a warm standby on cloud")
        assert (standby["app"], standby["placement"], standby["pool"], standby["robots"]) == (
            "object-detection",
            "cloud",
            "cloud",
            0,
        )
        # What it costs: the spec's requests, and the process' resident memory on the local backend.
        assert standby["requests"] == {"cpu": "1", "memory": "1Gi"} and standby["rssBytes"] > 10 * 2**20
        assert standby["pid"] in backend.pids().values() and mw.standbys()["rssBytes"] == standby["rssBytes"]
        with MiddlewareClient(server.url, "robot-2", ROBOTS["robot-2"]) as other:
            # Shared: a second robot on edge needs no second standby.
            assert other.deploy("object-detection", placement="edge", timeout=DEADLINE_S).url == edge.url
            assert len(backend.pids()) == 2 and len(mw.standbys()["standbys"]) == 1
            # A robot going to cloud takes the warm one as it is, Ready at once.
            started = time.monotonic()
            cloud = other.deploy("object-detection", placement="cloud", timeout=DEADLINE_S)
            assert cloud.url == standby["url"] and time.monotonic() - started < DEADLINE_S
            assert len(backend.pids()) == 2
        # robot-2 left: the cloud netapp is a standby again (robot-1 is still on edge).
        assert wait_until(lambda: ready_standbys(mw))[0]["netapp"] == standby["netapp"]
        mw.delete(edge)
        # No robot of the app left: after the idle grace the standby goes too, and every process with it.
        wait_until(lambda: mw.standbys()["standbys"] == [], what="the standby to be released")
        wait_until(lambda: backend.pids() == {}, what="every netapp to stop")


def test_a_routes_pool_is_readied_ahead_the_robot_moved_on_time_and_what_it_left_released(
    start_middleware: Any, tiny_model_path: Path
) -> None:
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S)
    server = start_middleware(backend, switchover=follow())
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        edge = mw.deploy("object-detection", placement="edge", timeout=2 * DEADLINE_S)
        (edge_pid,) = backend.pids().values()
        eta = time.time() + 300
        assert mw.route(edge, [("cloud", eta)]) == [{"pool": "cloud", "eta": eta}]
        (warm,) = wait_until(lambda: ready_standbys(mw), what="cloud to be readied ahead of the robot")
        view = mw.status(edge)
        assert view["pool"] == "edge" and view["history"] == []  # readied, not moved: the eta is 5 minutes off
        mw.route(edge, [("cloud", time.time() + 0.5)])  # the robot is nearly there
        moved = wait_until(lambda: mw.status(edge)["history"], what="the move on the route")
        assert (moved[0]["from"], moved[0]["to"], moved[0]["url"]) == ("edge", "cloud", warm["url"])
        assert "its route: on cloud" in moved[0]["message"] and moved[0]["seconds"] < 5
        # Behind it: the edge netapp goes (no robot reports here: after drain_s), the warm hold on cloud too.
        wait_until(lambda: edge_pid not in backend.pids().values(), what="the edge netapp to be released")
        wait_until(lambda: mw.standbys()["standbys"] == [], what="the warm hold to end")
        assert list(backend.pids()) == [warm["netapp"]] and mw.status(edge)["route"] == []


def test_a_move_on_a_route_loses_no_frame_and_the_tracker_state_goes_along(
    start_middleware: Any, tiny_model_path: Path, jpeg: bytes
) -> None:
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S)
    server = start_middleware(backend, switchover=follow())
    arrivals: list[tuple[float, str]] = []
    results: queue.Queue[Any] = queue.Queue()

    def received(result: Any) -> None:
        arrivals.append((time.monotonic(), result.source))
        results.put(result)

    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        edge = mw.deploy("object-tracking", placement="edge", timeout=2 * DEADLINE_S)
        (edge_pid,) = backend.pids().values()
        client = mw.netapp_client(
            edge, budget_ms=60_000, report_every_s=0.2, transport="ws", checkpoint_every=1, on_result=received
        )
        with client:
            send_until_result(lambda: client.send(jpeg), results)
            streaming = threading.Event()
            streaming.set()

            def stream() -> None:
                while streaming.is_set():
                    client.send(jpeg)
                    streaming.wait(0.04)  # a camera at 25 FPS

            sender = threading.Thread(target=stream, daemon=True)
            sender.start()
            try:
                mw.route(edge, [("cloud", time.time() + 300)])
                (warm,) = wait_until(lambda: ready_standbys(mw), what="cloud to be readied")
                mw.route(edge, [("cloud", time.time() + 0.3)])
                wait_until(lambda: client.url == warm["url"], what="the client to move")
                wait_until(lambda: edge_pid not in backend.pids().values(), what="the old netapp to go")
                released = time.monotonic()
                count = len(arrivals)
                wait_until(lambda: len(arrivals) > count + 5, what="results from cloud after the move")
            finally:
                streaming.clear()
                sender.join(5)
            assert client.wait_idle(DEADLINE_S)
        sources = [source for _, source in arrivals]
        assert sources[0] == edge.url and sources[-1] == warm["url"]
        first_cloud = next(t for t, source in arrivals if source == warm["url"])
        assert first_cloud < released  # the old netapp went only after the new one had answered
        assert client.stats.lost == 0 and client.stats.errors == 0  # not one frame lost to the move
        assert client.stats.restores >= 1  # the tracker's state went along (SET_STATE before its first frame)


def test_bad_routes_are_refused_with_one_line_each(start_middleware: Any) -> None:
    from tests.middleware.mw_helpers import NullBackend

    policy = AheadPolicy(max_waypoints=3, min_dwell_s=5.0, min_route_interval_s=0)
    server = start_middleware(NullBackend(), switchover=follow(policy))
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        view = mw.create("object-detection", placement="edge")
        now = time.time()
        for route, status, says in [
            ([("mars", now + 10)], 422, "unknown pool 'mars': the middleware serves edge, cloud"),
            ([("cloud", now - 60)], 422, "s in the past"),
            ([("cloud", now + 10 + 10 * i) for i in range(4)], 422, "at most 3 waypoints, got 4"),
            ([("cloud", now + 10), ("edge", now + 11)], 422, "flapping: cloud then edge 1.0 s later"),
        ]:
            with pytest.raises(MiddlewareError) as refused:
                mw.route(view["id"], route)
            assert refused.value.status == status and says in str(refused.value) and "\n" not in str(refused.value)
        token = mw._auth_header()
        url = f"{server.url}/deployments/{view['id']}/route"
        assert requests.put(url, data=b"x" * 5000, headers=token, timeout=5).status_code == 413
        assert requests.put(url, json={"route": "cloud"}, headers=token, timeout=5).status_code == 422
        assert mw.standbys()["routesRefused"] == 4 and mw.status(view["id"])["route"] == []
        # A good route is followed; sent again at once where the middleware asks for a pause: 429.
        assert mw.route(view["id"], [("cloud", now + 60)])[0]["pool"] == "cloud"
    slow = start_middleware(NullBackend(), switchover=follow(AheadPolicy(min_route_interval_s=60)))
    with MiddlewareClient(slow.url, "robot-1", ROBOTS["robot-1"]) as mw:
        view = mw.create("object-detection", placement="edge")
        mw.route(view["id"], [("cloud", time.time() + 60)])
        with pytest.raises(MiddlewareError) as again:
            mw.route(view["id"], [("cloud", time.time() + 60)])
        assert again.value.status == 429 and "at most one route per 60 s" in str(again.value)


def test_a_5g_era_robot_gives_its_route_with_its_plan(start_middleware: Any) -> None:
    from tests.middleware.mw_helpers import NullBackend

    server = start_middleware(NullBackend(), switchover=follow())
    login = requests.post(f"{server.url}/Login", json={"Id": "robot-1", "Password": ROBOTS["robot-1"]}, timeout=5)
    headers = {"Authorization": f"Bearer {login.json()['token']}"}
    task = DEFAULT_CATALOGUE["object-detection"]["taskId"]
    eta = time.time() + 120
    plan = requests.post(
        f"{server.url}/Task/Plan",
        json={"TaskId": task, "Route": [{"Location": "cloud", "Eta": eta}]},
        headers=headers,
        timeout=5,
    )
    assert plan.status_code == 200 and plan.json()["Route"] == [{"pool": "cloud", "eta": eta}]
    iso = "2001-01-01T00:00:00+00:00"  # long past
    bad = requests.post(
        f"{server.url}/Task/Plan",
        json={"TaskId": task, "Route": [{"Location": "cloud", "Eta": iso}]},
        headers=headers,
        timeout=5,
    )
    assert bad.status_code == 400 and bad.json()["statusCode"] == 400 and "in the past" in bad.json()["message"]


def test_on_kubernetes_a_standby_is_a_netapp_of_its_own_with_events(kube_api: Any, start_middleware: Any) -> None:
    """The kubernetes backend: the standby is a NetApp on the next-best placement (StandbyWarming Event); a robot
    going there takes it; with no robot left it is deleted after the idle grace (StandbyReleased)."""
    from netapp_middleware.backends.kubernetes import KubernetesBackend

    from tests.middleware.mw_helpers import NS, Operator

    server = start_middleware(KubernetesBackend(NS, kube_api.new_kube()), catalogue=with_standby(), switchover=follow())
    operator = Operator(kube_api)
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        view = mw.create("object-detection", placement="edge")
        wait_until(lambda: len(operator.netapps()) == 2, what="the robot's NetApp and the standby")
        by_placement = {n["spec"]["placement"]["policy"]: name for name, n in operator.netapps().items()}
        assert set(by_placement) == {"edge", "cloud"}
        warm = by_placement["cloud"]
        operator.set_status(warm, "Ready", "http://10.0.0.2:5896", "cloud-pool")
        (row,) = wait_until(lambda: ready_standbys(mw), what="the standby Ready")
        assert (row["netapp"], row["url"], row["requests"]) == (
            warm,
            "http://10.0.0.2:5896",
            {"cpu": "1", "memory": "1Gi"},
        )
        mw.delete(view["id"])
        wait_until(lambda: operator.netapps() == {}, what="every NetApp deleted once no robot needs them")

        def reasons() -> list[str]:
            return [
                e["reason"]
                for e in kube_api.run(kube_api.kube.list("Event", NS))
                if e["involvedObject"]["name"] == warm
            ]

        found = wait_until(lambda: {"StandbyWarming", "StandbyReleased"} <= set(reasons()), what="the Events")
        assert found and reasons().count("StandbyWarming") == 1


def test_a_restarted_middleware_takes_its_warm_standby_back_without_warming_again(
    kube_api: Any, start_middleware: Any
) -> None:
    """The warm hold is recorded with its NetApp, beside the robots' claims, and the robot's route with its claim: a
    new middleware process (a rolling update) holds the same standby, warms no second one (one StandbyWarming Event,
    two NetApps), follows the route on, and releases the standby as before once no robot needs it."""
    import json

    from netapp_middleware.backends.kubernetes import KubernetesBackend
    from netapp_operator.constants import ANNOTATION_CLAIMS

    from tests.middleware.mw_helpers import NS, Operator

    operator = Operator(kube_api)

    def start() -> Any:
        return start_middleware(
            KubernetesBackend(NS, kube_api.new_kube()), catalogue=with_standby(), switchover=follow()
        )

    def claims(name: str) -> set[str]:
        annotations = operator.netapps().get(name, {}).get("metadata", {}).get("annotations", {})
        return set(json.loads(annotations.get(ANNOTATION_CLAIMS) or "{}"))

    def warmings(name: str) -> int:
        events = kube_api.run(kube_api.kube.list("Event", NS))
        return sum(1 for e in events if e["involvedObject"]["name"] == name and e["reason"] == "StandbyWarming")

    first = start()
    # Not closed: closing a client deletes its deployments, and the robot's must outlive the restart.
    robot = MiddlewareClient(first.url, "robot-1", ROBOTS["robot-1"])
    view = robot.create("object-detection", placement="edge")
    eta = time.time() + 1800  # on cloud in half an hour: the route outlives the restart
    assert robot.route(view["id"], [("cloud", eta)]) == [{"pool": "cloud", "eta": eta}]
    wait_until(lambda: len(operator.netapps()) == 2, what="the robot's NetApp and the standby")
    warm = next(name for name, n in operator.netapps().items() if n["spec"]["placement"]["policy"] == "cloud")
    operator.set_status(warm, "Ready", "http://10.0.0.2:5896", "cloud-pool")
    wait_until(lambda: warmings(warm) == 1, what="the StandbyWarming Event")
    wait_until(lambda: claims(warm) == {"warm:object-detection:cloud"}, what="the warm hold recorded")
    first.__exit__(None, None, None)
    assert set(operator.netapps()) == {view["netapp"], warm}  # a restart releases nothing

    second = start()
    with MiddlewareClient(second.url, "robot-1", ROBOTS["robot-1"]) as mw:
        (row,) = wait_until(lambda: ready_standbys(mw), what="the standby taken back")
        assert (row["netapp"], row["url"]) == (warm, "http://10.0.0.2:5896")
        again = mw.status(view["id"])
        assert again["netapp"] == view["netapp"] and again["route"] == [{"pool": "cloud", "eta": eta}]
        assert set(operator.netapps()) == {view["netapp"], warm} and warmings(warm) == 1  # no second warm-up
        mw.delete(view["id"])
    wait_until(lambda: operator.netapps() == {}, what="the standby released once no robot needs it")
    assert warmings(warm) == 1
