"""Scale to zero on the API emulator (kopf and the real handlers): a NetApp with `spec.scaling.idleToZero` whose one
pod (a loopback /metrics standing in for its netapp) serves no robot goes to zero replicas, `phase: Idle`, keeping
its Service and URL; a new wake annotation brings its replicas back; a robot, or a pod still starting, keeps it up."""

from __future__ import annotations

import asyncio
import contextlib
import http.server
import threading
from collections.abc import Iterator
from typing import Any

import pytest
from netapp_operator import idle, render
from netapp_operator.config import OperatorConfig
from netapp_operator.constants import ANNOTATION_WAKE
from netapp_operator.spec import parse

from netapp.protocol import METRIC_ROBOTS
from tests.operator.op_harness import running_operator
from tests.operator.op_helpers import eventually, get_status, netapp, setup_pools
from tests.operator.test_operator_rollout_e2e import ready_pod

CONFIG = OperatorConfig(check_interval_seconds=0.2, idle_poll_seconds=0.1)


@contextlib.contextmanager
def metrics_server(robots: list[float]) -> Iterator[int]:
    """A netapp's /metrics on loopback, saying `robots[0]` robots (the test changes it); yields its port."""

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 (http.server's name)
            body = f"# TYPE {METRIC_ROBOTS} gauge\n{METRIC_ROBOTS} {robots[0]}\n".encode()
            self.send_response(200 if self.path == "/metrics" else 404)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: Any) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        yield server.server_address[1]
    finally:
        server.shutdown()
        server.server_close()


async def replicas(api: Any) -> int | None:
    dep = await api.get("Deployment", "default", "det-edge")
    return None if dep is None else (dep.get("spec") or {}).get("replicas")


async def kubelet(api: Any, ready: bool = True) -> None:
    """The Deployment controller's and the kubelet's part: the pod (ready or starting) and the available count."""
    pod = ready_pod("det-edge-0", render.labels("det", "edge"))
    if not ready:
        pod["status"]["conditions"] = [{"type": "Ready", "status": "False"}]
    await api.apply(pod)
    count = 1 if ready else 0
    await api.patch_status(
        "Deployment", "default", "det-edge", {"replicas": 1, "readyReplicas": count, "availableReplicas": count}
    )


async def scaled_down(api: Any) -> None:
    """The Deployment controller at zero replicas: the pod gone, nothing available."""
    await api.delete("Pod", "default", "det-edge-0")
    await api.patch_status(
        "Deployment", "default", "det-edge", {"replicas": 0, "readyReplicas": 0, "availableReplicas": 0}
    )


async def test_an_idle_netapp_sleeps_at_zero_keeping_its_service_and_wakes_on_a_new_wake(emulator, api):
    robots = [0.0]
    with metrics_server(robots) as port:
        async with running_operator(emulator, CONFIG):
            await setup_pools(api)
            await api.apply(netapp("det", port=port, scaling={"idleToZero": "1s"}))
            await eventually(lambda: replicas(api), what="the Deployment")
            await kubelet(api)
            ready = await eventually(lambda: _phase(api, "Ready"), what="Ready")
            await eventually(lambda: _is(replicas(api), 0), timeout=30, what="zero replicas")
            await scaled_down(api)
            status = await eventually(lambda: _phase(api, "Idle"), what="phase Idle")
            assert status["url"] == ready["url"] and status["idle"]["since"]  # the URL kept for the robots
            assert await api.get("Service", "default", "det-edge") is not None

            body = await api.get("NetApp", "default", "det")
            await api.merge_patch("NetApp", "default", "det", {"metadata": {"annotations": {ANNOTATION_WAKE: "1"}}})
            await eventually(lambda: _is(replicas(api), 1), what="its replica back")
            await kubelet(api)
            status = await eventually(lambda: _phase(api, "Ready"), what="Ready again")
            assert not status.get("idle") and body is not None


async def test_a_robot_or_a_starting_pod_keeps_it_up(emulator, api):
    robots = [1.0]
    with metrics_server(robots) as port:
        async with running_operator(emulator, CONFIG):
            await setup_pools(api)
            await api.apply(netapp("det", port=port, scaling={"idleToZero": "1s"}))
            await eventually(lambda: replicas(api), what="the Deployment")
            await kubelet(api)
            await eventually(lambda: _phase(api, "Ready"), what="Ready")
            await asyncio.sleep(2.5)  # one robot: never idle
            assert await replicas(api) == 1
            robots[0] = 0.0
            await kubelet(api, ready=False)  # a pod starting again (its model loading): never scaled to zero
            await asyncio.sleep(2.5)
            assert await replicas(api) == 1 and not (await get_status(api, "det")).get("idle")
            await kubelet(api)
            await eventually(lambda: _is(replicas(api), 0), timeout=30, what="zero once the pod is ready and quiet")


@pytest.mark.parametrize(
    ("value", "seconds"), [("30s", 30.0), ("5m", 300.0), ("1.5h", 5400.0), ("250ms", 0.25), (90, 90.0), ("x", None)]
)
def test_durations(value, seconds):
    assert idle.duration_s(value) == seconds


def test_a_spec_that_cannot_sleep_says_why():
    assert parse({"image": "i", "scaling": {"idleToZero": "5m"}}).problems == ()
    assert "idleToZero" in parse({"image": "i", "scaling": {"idleToZero": "soon"}}).problems[0]
    both = {"image": "i", "scaling": {"idleToZero": "5m"}, "autoscaling": {"maxReplicas": 3}}
    assert "autoscaling" in parse(both).problems[0]


def test_the_quiet_clock_restarts_on_a_robot_a_starting_pod_and_a_wake():
    clock = idle.QuietClock()
    assert clock.observe(0.0, "", True, 0) == 0.0 and clock.observe(5.0, "", True, 0) == 5.0
    assert clock.observe(6.0, "", True, 1) == 0.0  # a robot
    clock.observe(7.0, "", True, 0)
    assert clock.observe(8.0, "", False, None) == 0.0  # a pod not ready
    clock.observe(9.0, "", True, 0)
    assert clock.observe(10.0, "w1", True, 0) == 0.0  # woken: a robot was just handed the URL
    assert clock.observe(11.0, "w1", True, None) == 0.0  # a pod that did not answer


def test_asleep_until_the_wake_annotation_changes():
    body: dict[str, Any] = {"metadata": {"annotations": {ANNOTATION_WAKE: "a"}}, "status": {}}
    assert not idle.asleep(body)
    body["status"] = idle.idle_status(body, "2026-11-29T04:00:00Z")
    assert idle.asleep(body) and idle.wanted_replicas(body, 2) == 0
    body["metadata"]["annotations"][ANNOTATION_WAKE] = "b"
    assert not idle.asleep(body) and idle.wanted_replicas(body, 2) == 2
    assert idle.robots_in(f"{METRIC_ROBOTS}_other 3\n{METRIC_ROBOTS} 2\n") == 2.0


async def _phase(api: Any, phase: str) -> dict[str, Any]:
    status = await get_status(api, "det")
    return status if status.get("phase") == phase else {}


async def _is(value: Any, wanted: Any) -> bool:
    return await value == wanted


def test_an_asleep_netapp_renders_zero_replicas_and_an_awake_one_its_own():
    from netapp_operator.placement import Pool

    pool = Pool("edge", "edge", False, 1, {"nodeSelector": {"p": "e"}})
    body = netapp("det", replicas=2, scaling={"idleToZero": "5m"})
    body["metadata"].update(namespace="default", uid="u")
    spec = parse(body["spec"])
    assert render.render_deployment(body, spec, pool, CONFIG)["spec"]["replicas"] == 2
    body["status"] = idle.idle_status(body, "2026-11-29T04:00:00Z")
    assert render.render_deployment(body, spec, pool, CONFIG)["spec"]["replicas"] == 0
    new = idle.with_idle(body, {"phase": "Pending"})
    assert new["phase"] == idle.IDLE_PHASE and new["idle"]["since"] == "2026-11-29T04:00:00Z"
    body["metadata"]["annotations"] = {ANNOTATION_WAKE: "woken"}
    assert render.render_deployment(body, spec, pool, CONFIG)["spec"]["replicas"] == 2
    assert idle.with_idle(body, {"phase": "Deploying"}) == {"phase": "Deploying", "idle": None}
