"""Objects and waiting helpers shared by the operator tests."""

from __future__ import annotations

import asyncio
import contextlib
import os
import pathlib
import sys
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any, TypeVar

from tests.support.kube_emulator import kubeconfig

T = TypeVar("T")


async def eventually(
    probe: Callable[[], Awaitable[T]], timeout: float = 30.0, interval: float = 0.05, what: str = "condition"
) -> T:
    """Poll `probe` until it returns something truthy; fail with the last value after `timeout` seconds.

    The deadlines are generous on purpose: the test machines are small and shared."""
    deadline = time.monotonic() + timeout
    last: Any = None
    while True:
        last = await probe()
        if last:
            return last
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout}s waiting for {what}; last value: {last!r}")
        await asyncio.sleep(interval)


def node(name: str, labels: dict[str, str], ready: bool = True, address: str = "10.0.0.1") -> dict[str, Any]:
    return {
        "apiVersion": "v1",
        "kind": "Node",
        "metadata": {"name": name, "labels": labels},
        "status": {
            "conditions": [{"type": "Ready", "status": "True" if ready else "False"}],
            "addresses": [{"type": "InternalIP", "address": address}],
        },
    }


def nodepool(
    name: str,
    type_: str,
    selector: dict[str, str],
    *,
    gpu: bool = False,
    priority: int = 0,
    access: dict[str, Any] | None = None,
) -> dict[str, Any]:
    spec: dict[str, Any] = {"type": type_, "nodeSelector": selector, "gpu": gpu, "priority": priority}
    if access is not None:
        spec["access"] = access
    return {"apiVersion": "netapp.dev/v1alpha1", "kind": "NodePool", "metadata": {"name": name}, "spec": spec}


def netapp(name: str, namespace: str = "default", **spec: Any) -> dict[str, Any]:
    spec.setdefault("image", "ghcr.io/netapp-toolkit/netapp:0.1.0")
    return {
        "apiVersion": "netapp.dev/v1alpha1",
        "kind": "NetApp",
        "metadata": {"name": name, "namespace": namespace},
        "spec": spec,
    }


def condition(obj: dict[str, Any] | None, type_: str) -> dict[str, Any]:
    for cond in ((obj or {}).get("status") or {}).get("conditions", []) or []:
        if cond.get("type") == type_:
            return cond
    return {}


EDGE = {"netapp.dev/pool": "edge"}
CLOUD = {"netapp.dev/pool": "cloud"}


async def setup_pools(api: Any) -> None:
    """An edge pool (NodePort, preferred) and a cloud pool (ClusterIP behind a URL template), one node each."""
    await api.apply(node("edge-1", EDGE, address="192.168.1.10"))
    await api.apply(node("cloud-1", CLOUD, address="10.1.0.10"))
    await api.apply(nodepool("edge", "edge", EDGE, priority=10, access={"serviceType": "NodePort"}))
    await api.apply(
        nodepool(
            "cloud",
            "cloud",
            CLOUD,
            access={"serviceType": "ClusterIP", "urlTemplate": "https://{name}.{namespace}.cloud.example.com"},
        )
    )


async def get_status(api: Any, name: str, namespace: str = "default") -> dict[str, Any]:
    na = await api.get("NetApp", namespace, name)
    return (na or {}).get("status") or {}


@contextlib.asynccontextmanager
async def operator_command(
    emulator_url: str, directory: pathlib.Path, *flags: str
) -> AsyncIterator[asyncio.subprocess.Process]:
    """`netapp operator --all-namespaces FLAGS` as a real process, logged in to the emulator through a kubeconfig;
    terminated at the end."""
    config = directory / "kubeconfig"
    config.write_text(kubeconfig(emulator_url.rstrip("/")))
    proc = await asyncio.create_subprocess_exec(
        *(sys.executable, "-m", "netapp", "--log-level", "WARNING", "operator", "--all-namespaces", *flags),
        env={**os.environ, "KUBECONFIG": str(config)},
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT,
    )
    try:
        yield proc
    finally:
        if proc.returncode is None:
            proc.terminate()
            try:
                await asyncio.wait_for(proc.wait(), timeout=20)
            except asyncio.TimeoutError:
                proc.kill()
                await proc.wait()
