"""The waker (docs/kubernetes.md#scale-to-zero): while a NetApp that may sleep has no ready pod, its Service gets the
operator's waker as an endpoint (an EndpointSlice), which answers a robot's request `waking` and wakes the NetApp.

The rendered slice and the Host matching, pure; then kopf and the real handlers on the API emulator, a real
`netapp serve` standing for the pod, a loopback relay standing for kube-proxy (it sends each connection to the
waker's EndpointSlice while the emulator has it, else to the pod), and a real robot client coming back to the URL it
holds: told to wait, retried, served."""

from __future__ import annotations

import asyncio
import contextlib
import queue
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from netapp_operator import idle, render, wake_listener, waker
from netapp_operator.config import OperatorConfig
from netapp_operator.spec import parse
from netapp_operator.wake_listener import host_of

from netapp.client.netapp_client import NetAppClient
from netapp.serve_process import NetAppProcess, free_port
from tests.middleware.mw_helpers import send_until_result
from tests.operator.op_harness import denied_requests, running_operator
from tests.operator.op_helpers import EDGE, eventually, get_status, netapp, node, nodepool
from tests.operator.test_operator_idle import kubelet, replicas, scaled_down

BODY = {"metadata": {"name": "det", "namespace": "default", "uid": "u-1"}, "status": {"pool": "edge"}}


def test_the_waker_s_slice_joins_the_netapp_s_service_on_its_http_port():
    slice_ = waker.render_slice(BODY, "edge", "10.244.1.7", 8083)
    assert slice_["metadata"]["name"] == render.child_name("det", "edge")
    labels = slice_["metadata"]["labels"]
    assert labels[waker.SERVICE_NAME_LABEL] == "det-edge" and labels[waker.SLICE_MANAGED_BY_LABEL] != (
        "endpointslice-controller.k8s.io"  # the controller's: it would delete ours
    )
    assert slice_["addressType"] == "IPv4" and slice_["endpoints"][0]["addresses"] == ["10.244.1.7"]
    assert slice_["ports"] == [{"name": "http", "port": 8083, "protocol": "TCP"}]
    assert slice_["metadata"]["ownerReferences"][0]["uid"] == "u-1"
    assert waker.render_slice(BODY, "edge", "fd00::7", 8083)["addressType"] == "IPv6"


def test_fronted_while_a_netapp_that_may_sleep_has_no_ready_pod_and_not_over_tls():
    sleeps = parse({"image": "i", "scaling": {"idleToZero": "5m"}})
    assert waker.fronted(sleeps, None) and waker.fronted(sleeps, {"status": {"replicas": 1}})
    assert not waker.fronted(sleeps, {"status": {"readyReplicas": 1}})
    assert not waker.fronted(parse({"image": "i"}), None)  # never sleeps: as before
    tls = parse({"image": "i", "scaling": {"idleToZero": "5m"}, "tls": {"secretName": "s"}})
    assert not waker.fronted(tls, None)  # the waker cannot answer for its certificate


def test_a_request_is_matched_to_its_netapp_by_host_then_by_node_port():
    spec = parse({"image": "i", "port": 8080, "scaling": {"idleToZero": "5m"}})
    body = {**BODY, "status": {"pool": "edge", "url": "http://192.168.1.10:30001"}}
    service = {"spec": {"clusterIP": "10.96.0.12", "ports": [{"name": "http", "port": 8080, "nodePort": 30001}]}}
    other = ({"metadata": {"name": "seg", "namespace": "lab"}, "status": {"pool": "edge"}}, spec, None)
    candidates = [
        (("lab", "seg"), *waker.addresses(*other)),
        (("default", "det"), *waker.addresses(body, spec, service)),
    ]
    for host in ("192.168.1.10:30001", "det-edge.default.svc.cluster.local:8080", "det-edge:8080", "10.96.0.12:8080"):
        assert waker.netapp_at(host, candidates) == ("default", "det"), host
    assert waker.netapp_at("10.0.0.99:30001", candidates) == ("default", "det")  # another node's address
    assert waker.netapp_at("seg-edge.lab:8080", candidates) == ("lab", "seg")
    for host in ("192.168.1.10:30002", "elsewhere.example.com", "[::1", "x:99999", ""):
        assert waker.netapp_at(host, candidates) is None, host
    assert host_of(b"GET / HTTP/1.1\r\nHOST:  Det-Edge:8080 \r\n\r\n") == "det-edge:8080"
    assert host_of(b"garbage") == "" and host_of(b"GET / HTTP/1.1\r\nX: host:1\r\n\r\n") == ""


# --- on the API emulator --------------------------------------------------------------------------------------------


@contextlib.asynccontextmanager
async def kube_proxy(api: Any, pod_port: int) -> AsyncIterator[int]:
    """The Service on loopback: each connection goes to the waker's EndpointSlice while the emulator has one, else
    to the pod (its port); yields the port it listens on."""

    async def pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        with contextlib.suppress(ConnectionError, OSError):
            while data := await reader.read(65536):
                writer.write(data)
                await writer.drain()
        writer.close()

    async def connect(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        found = await api.get("EndpointSlice", "default", "det-edge")
        host, port = ("127.0.0.1", pod_port)
        if found is not None:
            host, port = found["endpoints"][0]["addresses"][0], found["ports"][0]["port"]
        try:
            upstream = await asyncio.open_connection(host, port)
        except OSError:  # nothing there yet: refused, as kube-proxy's REJECT
            writer.close()
            return
        await asyncio.gather(pipe(reader, upstream[1]), pipe(upstream[0], writer))

    server = await asyncio.start_server(connect, "127.0.0.1", 0)
    async with server:
        yield server.sockets[0].getsockname()[1]


async def slice_of(api: Any) -> dict[str, Any] | None:
    return await api.get("EndpointSlice", "default", "det-edge")


async def no_slice(api: Any) -> bool:
    return await slice_of(api) is None


async def replicas_are(api: Any, wanted: int) -> bool:
    return await replicas(api) == wanted


async def phase(api: Any, wanted: str) -> dict[str, Any]:
    status = await get_status(api, "det")
    return status if status.get("phase") == wanted else {}


async def test_a_robot_holding_the_url_of_a_sleeping_netapp_is_told_to_wait_and_served(
    emulator: Any, api: Any, tiny_model_path: Path, jpeg: bytes
) -> None:
    waker_port = free_port()
    config = OperatorConfig(
        check_interval_seconds=0.2, idle_poll_seconds=0.1, waker_ip="127.0.0.1", waker_port=waker_port
    )
    pod = NetAppProcess("--model", str(tiny_model_path))  # the NetApp's one pod, started and stopped as told
    async with kube_proxy(api, pod.port) as service_port, running_operator(emulator, config) as operator:
        await api.apply(node("edge-1", EDGE, address="127.0.0.1"))
        await api.apply(nodepool("edge", "edge", EDGE, access={"serviceType": "ClusterIP", "host": "127.0.0.1"}))
        await api.apply(netapp("det", port=service_port, scaling={"idleToZero": "1s"}))
        # Starting: no ready pod, so the waker fronts its Service; once the pod is ready, its slice goes.
        fronting = await eventually(lambda: slice_of(api), what="the waker's EndpointSlice")
        assert fronting["endpoints"][0]["addresses"] == ["127.0.0.1"] and fronting["ports"][0]["port"] == waker_port
        try:
            await asyncio.to_thread(lambda: pod.start().wait_ready())
            await kubelet(api)
            await eventually(lambda: no_slice(api), what="the slice gone once a pod is ready")
            await eventually(lambda: replicas_are(api, 0), timeout=30, what="zero replicas, no robot")
            pod.kill()
            await scaled_down(api)
            asleep = await eventually(lambda: phase(api, idle.IDLE_PHASE), what="phase Idle")
            assert asleep["url"] == f"http://127.0.0.1:{service_port}"
            await eventually(lambda: slice_of(api), what="the waker's slice while it sleeps")

            # A robot comes back to the URL it holds: the waker answers `waking` and wakes it; the robot retries.
            results: queue.Queue[Any] = queue.Queue()
            robot = asyncio.ensure_future(asyncio.to_thread(_robot, asleep["url"], jpeg, results))
            await eventually(lambda: replicas_are(api, 1), what="woken by the robot's request")
            runtime_waker = operator.runtime.waker
            assert runtime_waker is not None and runtime_waker.waking > 0 and runtime_waker.unknown == 0
            await asyncio.to_thread(lambda: pod.start().wait_ready())  # its pod starts again, on the same port
            await kubelet(api)
            first = await asyncio.wait_for(robot, timeout=60)
            assert first.detections and not (await get_status(api, "det")).get("idle")
            await eventually(lambda: no_slice(api), what="the slice gone again")
        finally:
            pod.kill()


def _robot(url: str, jpeg: bytes, results: queue.Queue[Any]) -> Any:
    """A robot's session at `url` (told to wait, retried within its 30 s to connect) and its first result."""
    with NetAppClient(url, on_result=results.put, connect_timeout_s=30) as client:
        return send_until_result(lambda: client.send(jpeg), results)


async def test_the_wake_listener_bounds_what_a_stranger_can_hold(monkeypatch) -> None:
    """A head past MAX_HEAD_BYTES is answered without it (b""); past MAX_CONNECTIONS a connection is closed
    unanswered and counted."""
    monkeypatch.setattr(wake_listener, "MAX_CONNECTIONS", 2)
    heads: list[bytes] = []
    listener = wake_listener.WakeListener(lambda head: heads.append(head) or wake_listener.waking_answer())
    await listener.open("127.0.0.1", 0)
    assert listener.port is not None
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", listener.port)
        writer.write(b"GET / HTTP/1.1\r\nX: " + b"a" * (wake_listener.MAX_HEAD_BYTES + 10))
        answer = await reader.read()
        assert answer.startswith(b"HTTP/1.1 503") and b'"waking"' in answer and heads == [b""]
        writer.close()
        held = [await asyncio.open_connection("127.0.0.1", listener.port) for _ in range(2)]  # sending nothing
        await eventually(_open_is(listener, 2), what="two connections held")
        reader, writer = await asyncio.open_connection("127.0.0.1", listener.port)
        assert await reader.read() == b"" and listener.refused == 1  # the third: closed unanswered
        for _, held_writer in held:
            held_writer.close()
        writer.close()
    finally:
        await listener.close()


def _open_is(listener: wake_listener.WakeListener, count: int) -> Any:
    async def probe() -> bool:
        return listener._open == count

    return probe


async def test_a_restarted_operator_points_the_slice_at_itself_and_removes_it_once_unwanted(emulator: Any, api: Any):
    """The slice outlives the operator (it is the NetApp's): a new operator pod (another IP) rewrites the address of
    one still wanted, and deletes one that is no longer (its NetApp's pod became ready meanwhile)."""
    base = {"check_interval_seconds": 0.2, "idle_poll_seconds": 0.1, "waker_port": free_port()}
    await api.apply(node("edge-1", EDGE, address="127.0.0.1"))
    await api.apply(nodepool("edge", "edge", EDGE, access={"serviceType": "ClusterIP", "host": "127.0.0.1"}))
    await api.apply(netapp("det", port=free_port(), scaling={"idleToZero": "1h"}))
    async with running_operator(emulator, OperatorConfig(**base, waker_ip="127.0.0.1")):
        await eventually(lambda: slice_of(api), what="the waker's slice of a starting NetApp")
    async with running_operator(emulator, OperatorConfig(**base, waker_ip="127.0.0.2")):

        async def moved() -> bool:
            found = await slice_of(api)
            return found is not None and found["endpoints"][0]["addresses"] == ["127.0.0.2"]

        await eventually(moved, what="the slice at the new operator's address")
    await kubelet(api)  # its pod ready while no operator runs
    async with running_operator(emulator, OperatorConfig(**base, waker_ip="127.0.0.2")):
        await eventually(lambda: no_slice(api), what="the leftover slice removed")
    denied, _ = denied_requests(emulator)  # the waker's requests too: the chart's role allows them
    assert not denied, f"the operator needs permissions its ClusterRole lacks: {denied}"
