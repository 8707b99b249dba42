"""Switchover that triggers itself, end to end: a robot streaming to its netapp reports a latency over its budget,
the middleware starts a netapp on another placement, moves the robot there once it is Ready (make before break)
and releases the old one once the robot reports from the new one; the reasons are in the deployment's view, the
log and, on Kubernetes, Events on the NetApps."""

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
from netapp_middleware.switchover.decision import MOVED, STAY_NO_BETTER, SwitchPolicy

from netapp.client.middleware import MiddlewareClient
from tests.middleware.mw_helpers import DEADLINE_S, NS, ROBOTS, Operator, send_until_result, wait_until

FAST = {"policy": SwitchPolicy(sustain_s=0.5, min_dwell_s=0.0), "min_interval_s": 0.05}


def test_an_over_budget_robot_is_moved_make_before_break_while_streaming(
    start_middleware: Any, tiny_model_path: Path, jpeg: bytes, caplog: pytest.LogCaptureFixture
) -> None:
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S)
    # Netapps that need a token: the new one has a token of its own, which the client takes along when it moves.
    protected = {"object-detection": {**DEFAULT_CATALOGUE["object-detection"], "allowUnauthenticated": False}}
    server = start_middleware(backend, catalogue=protected, switchover=FAST)
    results: queue.Queue[Any] = queue.Queue()
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        edge = mw.deploy("object-detection", placement="edge", timeout=2 * DEADLINE_S)
        assert edge.pool == "edge"
        (edge_pid,) = backend.pids().values()
        # A budget no netapp on this machine meets (a millisecond's hundredth): the robot is over it from the start.
        with mw.netapp_client(edge, budget_ms=0.01, report_every_s=0.2, transport="ws", on_result=results.put) as c:
            send_until_result(lambda: c.send(jpeg), results)
            streaming = threading.Event()
            streaming.set()

            def stream() -> None:
                while streaming.is_set():
                    c.send(jpeg)
                    time.sleep(0.04)

            sender = threading.Thread(target=stream, daemon=True)
            sender.start()
            try:
                moved = wait_until(lambda: mw.status(edge)["history"], what="the switchover")
                assert [(m["from"], m["to"], m["reason"]) for m in moved] == [("edge", "cloud", MOVED)]
                view = mw.status(edge)
                assert view["pool"] == "cloud" and view["url"] == moved[0]["url"] != edge.url
                assert "moved from edge to cloud" in view["message"]
                wait_until(lambda: c.url == view["url"], what="the client to follow the move")
                assert c.token == view["token"] != edge.token and edge.token
                # The old netapp goes once the robot reports from the new one.
                wait_until(lambda: edge_pid not in backend.pids().values(), what="the old netapp to stop")
                got = c.stats.results
                wait_until(lambda: c.stats.results > got + 5, what="results from the new netapp")
                # Cloud is over budget too and edge was worse: the robot stays (no flapping back).
                wait_until(lambda: STAY_NO_BETTER in caplog.text or None, what="the decision to stay on cloud")
            finally:
                streaming.clear()
                sender.join(5)
            assert len(mw.status(edge)["history"]) == 1
            assert c.stats.errors == 0
            # Nothing lost but the frames in flight at the switch.
            assert c.stats.lost <= c.max_in_flight, c.stats.summary(1.0)
        assert len(backend.pids()) == 1


def test_reports_are_bounded_and_rate_limited(start_middleware: Any, tiny_model_path: Path) -> None:
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S)
    server = start_middleware(backend, switchover={"min_interval_s": 5.0})
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        view = mw.create("object-detection", placement="edge")
        headers = mw._auth_header()
        url = f"{server.url}/deployments/{view['id']}/report"
        big = requests.post(url, headers=headers, data=b'{"p95_ms": 1, "deadline_ms": 1, "x": "' + b"a" * 2000 + b'"}')
        assert big.status_code == 413, big.text
        bad = requests.post(url, headers=headers, json={"p95_ms": -1, "deadline_ms": 100})
        assert bad.status_code == 422 and "p95_ms" in bad.json()["error"]
        assert mw.report(view["id"], 5.0, 100.0, 0, 1.0)["reason"] == "WithinBudget"
        again = requests.post(url, headers=headers, json={"p95_ms": 5, "deadline_ms": 100})
        assert again.status_code == 429 and "report less often" in again.json()["error"]
        other = requests.post(
            f"{server.url}/deployments/not-mine/report", headers=headers, json={"p95_ms": 5, "deadline_ms": 100}
        )
        assert other.status_code == 404
        assert requests.post(url, json={"p95_ms": 5, "deadline_ms": 100}).status_code == 401


def test_on_kubernetes_the_decisions_are_events_on_the_netapps(kube_api: Any, start_middleware: Any) -> None:
    """The kubernetes backend: the move creates a NetApp on the new placement, waits for it to be Ready, moves the
    robot, deletes the old NetApp once the robot reports from the new one, and posts Events on both."""
    from netapp_middleware.backends.kubernetes import KubernetesBackend

    server = start_middleware(KubernetesBackend(NS, kube_api.new_kube()), switchover=FAST)
    operator = Operator(kube_api)
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        view = mw.create("object-detection", placement="edge")
        old = operator.the_one()["metadata"]["name"]
        operator.set_status(old, "Ready", "http://10.0.0.1:5896", "edge-pool")
        wait_until(lambda: mw.status(view["id"])["status"] == "Ready", what="Ready")

        def report_slow() -> bool:
            mw.report(view["id"], 400.0, 100.0, 10, 0.2, url="http://10.0.0.1:5896")
            time.sleep(0.1)
            return len(operator.netapps()) == 2

        wait_until(report_slow, what="a NetApp on the cloud placement")
        (new,) = set(operator.netapps()) - {old}
        assert operator.netapps()[new]["spec"]["placement"] == {"policy": "cloud"}
        assert mw.status(view["id"])["url"] == "http://10.0.0.1:5896"  # not Ready yet: the robot stays
        operator.set_status(new, "Ready", "http://10.0.0.2:5896", "cloud-pool")
        moved = wait_until(lambda: mw.status(view["id"])["history"], what="the move")
        assert (moved[0]["from"], moved[0]["to"], moved[0]["pool"]) == ("edge", "cloud", "cloud-pool")
        assert old in operator.netapps()  # make before break: the robot has not reported from the new one
        time.sleep(FAST["min_interval_s"])  # reports are rate-limited: space them
        stale = mw.report(view["id"], 900.0, 100.0, 0, 0.2, url="http://10.0.0.1:5896")
        assert stale["reason"] == "StaleReport" and old in operator.netapps()  # measured on the old one: ignored
        time.sleep(FAST["min_interval_s"])
        mw.report(view["id"], 20.0, 100.0, 0, 0.2, url="http://10.0.0.2:5896")
        wait_until(lambda: old not in operator.netapps(), what="the old NetApp to be deleted")

        def events() -> dict[str, set[str]]:
            found: dict[str, set[str]] = {}
            for event in kube_api.run(kube_api.kube.list("Event", NS)):
                found.setdefault(event["involvedObject"]["name"], set()).add(event["reason"])
            return found

        wait_until(lambda: "SwitchingOver" in events().get(old, set()), what="the SwitchingOver event")
        assert MOVED in wait_until(lambda: events().get(new), what="the SwitchedOver event")
        (switched,) = [e for e in kube_api.run(kube_api.kube.list("Event", NS)) if e["reason"] == MOVED]
        assert "moved from edge to cloud" in switched["message"] and switched["type"] == "Normal"
        assert switched["source"]["component"] == "netapp-middleware"


def test_into_a_warm_standby_the_first_report_over_budget_moves_the_robot_losing_nothing(
    start_middleware: Any, tiny_model_path: Path, jpeg: bytes
) -> None:
    """A cold move waits an hour here (`sustain_s`): only the warm path (`warm_sustain_s`, 0) can move the robot,
    into the catalogue's standby, on the first report over budget, and the hedged move loses no frame."""
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S)
    standby = {"object-detection": {**DEFAULT_CATALOGUE["object-detection"], "standby": "nextBest"}}
    policy = SwitchPolicy(sustain_s=3600.0, min_dwell_s=0.0, trend_horizon_s=0)
    server = start_middleware(backend, catalogue=standby, switchover={**FAST, "policy": policy, "tick_s": 0.05})
    results: queue.Queue[Any] = queue.Queue()
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        edge = mw.deploy("object-detection", placement="edge", timeout=2 * DEADLINE_S)
        (warm,) = wait_until(
            lambda: [s for s in mw.standbys()["standbys"] if s["phase"] == "Ready"], what="the warm standby on cloud"
        )
        budget = {"ms": 1000.0}
        with mw.netapp_client(
            edge, budget_ms=lambda: budget["ms"], report_every_s=0.2, transport="ws", on_result=results.put
        ) as c:
            send_until_result(lambda: c.send(jpeg), results)
            budget["ms"] = 0.01  # a budget no netapp here meets: every report from now on is over it
            deadline = time.monotonic() + DEADLINE_S
            while c.url == edge.url and time.monotonic() < deadline:
                c.send(jpeg)
                time.sleep(0.04)  # pacing the robot's frames, not synchronisation
            (moved,) = mw.status(edge)["history"]
            assert (moved["to"], moved["url"], moved["netapp"]) == ("cloud", warm["url"], warm["netapp"])
            assert "a netapp is Ready there" in moved["message"] and "for 0.0 s" in moved["message"]
            assert c.url == warm["url"] and c.stats.lost == 0, c.stats.summary(1.0)


def test_without_a_standby_the_first_report_over_budget_starts_the_new_netapp_and_the_robot_moves_once_ready(
    start_middleware: Any, tiny_model_path: Path, jpeg: bytes
) -> None:
    """No standby, and a cold move would wait an hour (`sustain_s`): only the netapp started ahead of the move
    (`Decision.prepare`) can move the robot, the moment it is Ready, into it; the hedged move loses no frame."""
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S)
    policy = SwitchPolicy(sustain_s=3600.0, min_dwell_s=0.0, trend_horizon_s=0)
    server = start_middleware(backend, switchover={**FAST, "policy": policy})
    results: queue.Queue[Any] = queue.Queue()
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        edge = mw.deploy("object-detection", placement="edge", timeout=2 * DEADLINE_S)
        budget = {"ms": 1000.0}
        with mw.netapp_client(
            edge, budget_ms=lambda: budget["ms"], report_every_s=0.2, transport="ws", on_result=results.put
        ) as c:
            send_until_result(lambda: c.send(jpeg), results)
            assert len(backend.pids()) == 1 and not mw.standbys()["standbys"]
            budget["ms"] = 0.01  # a budget no netapp here meets: every report from now on is over it
            deadline = time.monotonic() + DEADLINE_S
            while c.url == edge.url and time.monotonic() < deadline:
                c.send(jpeg)
                time.sleep(0.04)  # pacing the robot's frames, not synchronisation
            (moved,) = mw.status(edge)["history"]
            assert moved["to"] == "cloud" and "a netapp is Ready there" in moved["message"]
            assert c.url == moved["url"] != edge.url and c.stats.lost == 0, c.stats.summary(1.0)
            got = c.stats.results
            while c.stats.results <= got and time.monotonic() < deadline:
                c.send(jpeg)
                time.sleep(0.04)
            assert c.stats.results > got and c.stats.errors == 0
