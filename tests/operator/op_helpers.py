"""Objects and waiting helpers shared by the operator tests."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

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
