"""End to end on the kubernetes backend: the API emulator, `netapp operator` and `netapp middleware` as real
processes, the test playing the kubelet (it serves a real netapp on loopback at the URL the NetApp's status names
and marks its Deployment available). A robot deploys, gets the URL, streams, gets detections, survives a pool
failure (failover to another pool, new URL) and deletes."""

from __future__ import annotations

import os
import queue
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest
import requests

from netapp.client.middleware import Endpoint, MiddlewareClient
from tests.middleware.mw_helpers import DEADLINE_S, ROBOTS, EmulatedCluster, free_port, send_until_result, wait_until
from tests.support.paths import ROOT

pytest.importorskip("kopf", reason="the operator extra is not installed")

pytestmark = pytest.mark.timeout(300)
NS = "robots"
EDGE, CLOUD = {"netapp.dev/pool": "edge"}, {"netapp.dev/pool": "cloud"}


class Cluster(EmulatedCluster):
    """The emulated cluster with node pools, as the operator sees them."""

    def add_pool(self, name: str, selector: dict[str, str], priority: int) -> None:
        node = {
            "apiVersion": "v1",
            "kind": "Node",
            "metadata": {"name": f"{name}-1", "labels": selector},
            "status": {
                "conditions": [{"type": "Ready", "status": "True"}],
                "addresses": [{"type": "InternalIP", "address": "127.0.0.1"}],
            },
        }
        pool = {
            "apiVersion": "netapp.dev/v1alpha1",
            "kind": "NodePool",
            "metadata": {"name": name},
            "spec": {
                "type": name,
                "nodeSelector": selector,
                "priority": priority,
                "access": {"serviceType": "NodePort"},
            },
        }
        self.run(self.kube.create(node))
        self.run(self.kube.create(pool))

    def netapps(self) -> list[dict[str, Any]]:
        return self.run(self.kube.list("NetApp", NS))

    def deployment_names(self) -> set[str]:
        return {d["metadata"]["name"] for d in self.run(self.kube.list("Deployment", NS))}


@pytest.fixture()
def pooled_cluster(tmp_path: Path) -> Iterator[Cluster]:
    cluster = Cluster(tmp_path)
    yield cluster
    cluster.close()


def start(argv: list[str], kubeconfig_path: Path, log: Path) -> subprocess.Popen[bytes]:
    with open(log, "wb") as out:
        return subprocess.Popen(
            [sys.executable, "-m", "netapp", *argv],
            cwd=ROOT,
            stdout=out,
            stderr=subprocess.STDOUT,
            env={**os.environ, "KUBECONFIG": str(kubeconfig_path)},
        )


def stop(process: subprocess.Popen[bytes]) -> None:
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def test_robot_deploys_streams_fails_over_and_deletes(
    pooled_cluster: Cluster, kubelet: Any, robots_file: Path, tmp_path: Path, jpeg: bytes
) -> None:
    cluster = pooled_cluster
    cluster.add_pool("edge", EDGE, priority=10)
    cluster.add_pool("cloud", CLOUD, priority=0)
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    operator = start(
        ["operator", "--all-namespaces", "--liveness", "", "--failover-grace", "1", "--check-interval", "0.5"],
        cluster.kubeconfig,
        tmp_path / "operator.log",
    )
    middleware = start(
        [
            "middleware",
            "--backend",
            "kubernetes",
            "--namespace",
            NS,
            "--kubeconfig",
            str(cluster.kubeconfig),
            "--robots-file",
            str(robots_file),
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
        ],
        cluster.kubeconfig,
        tmp_path / "middleware.log",
    )
    logs = lambda: "\n".join(f"--- {p.name}\n{p.read_text()[-3000:]}" for p in tmp_path.glob("*.log"))  # noqa: E731
    try:

        def healthy() -> bool:
            assert middleware.poll() is None and operator.poll() is None, logs()
            try:
                return requests.get(f"{url}/healthz", timeout=2).ok
            except requests.RequestException:
                return False

        wait_until(healthy, what="the middleware")
        results: queue.Queue[Any] = queue.Queue()
        progress: list[str] = []
        with MiddlewareClient(url, "robot-1", ROBOTS["robot-1"]) as mw:
            deployed: dict[str, Any] = {}
            thread = threading.Thread(
                target=lambda: deployed.update(
                    endpoint=mw.deploy(
                        "object-detection",
                        placement="auto",
                        timeout=2 * DEADLINE_S,
                        on_progress=lambda view: progress.append(view["status"]),
                    )
                )
            )
            thread.start()

            # The kubelet's part: serve the netapp where the operator says, and report its Deployment available.
            first = play_kubelet(cluster, kubelet, "edge", logs)
            thread.join(2 * DEADLINE_S)
            endpoint: Endpoint = deployed.get("endpoint")
            assert endpoint is not None, logs()
            assert (endpoint.url, endpoint.pool) == (first, "edge")
            assert progress[-1] == "Ready" and "Pending" in progress
            with mw.netapp_client(endpoint, transport="ws", on_result=results.put) as client:
                result = send_until_result(lambda: client.send(jpeg), results)
                assert [d["class_name"] for d in result.detections] == ["robot"]

                # The edge pool fails: the operator moves the NetApp to the cloud pool, with a new URL.
                cluster.run(
                    cluster.kube.patch_status(
                        "Node", None, "edge-1", {"conditions": [{"type": "Ready", "status": "False"}]}
                    )
                )
                second = play_kubelet(cluster, kubelet, "cloud", logs)
                assert second != first
                wait_until(lambda: client.url == second, what="the robot to follow the failover")
                kubelet.stop("edge")
                while not results.empty():
                    results.get_nowait()
                result = send_until_result(lambda: client.send(jpeg), results)
                assert [d["class_name"] for d in result.detections] == ["robot"]
            assert mw.status(endpoint)["pool"] == "cloud"
        # Leaving the block deleted the deployment: the NetApp and its children are gone.
        wait_until(
            lambda: not cluster.netapps() and not cluster.deployment_names(),
            what="the NetApp and its Deployments to be deleted",
        )
    finally:
        stop(middleware)
        stop(operator)


def play_kubelet(cluster: Cluster, kubelet: Any, pool: str, logs: Any) -> str:
    """Wait until the operator names a URL on `pool`, serve a netapp on its port, mark the Deployment available."""

    def placed() -> dict[str, Any] | None:
        for netapp in cluster.netapps():
            status = netapp.get("status") or {}
            if status.get("pool") == pool and status.get("url"):
                return netapp
        return None

    netapp = wait_until(placed, what=f"the operator to place the NetApp on {pool}")
    netapp_url = netapp["status"]["url"]
    split = urlsplit(netapp_url)
    assert split.hostname == "127.0.0.1", netapp_url
    assert kubelet.serve(pool, port=split.port) == netapp_url
    deployment = f"{netapp['metadata']['name']}-{pool}"
    wait_until(lambda: deployment in cluster.deployment_names(), what=f"Deployment {deployment}")
    ready = {"replicas": 1, "readyReplicas": 1, "availableReplicas": 1, "updatedReplicas": 1}
    cluster.run(cluster.kube.patch_status("Deployment", NS, deployment, ready))
    return netapp_url
