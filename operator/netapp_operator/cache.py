"""What the operator has seen on its watches: nodes, pools, netapps and their children (no I/O).

Placement and status checks read from here, so the periodic check costs no API call unless something changed.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from netapp_operator.placement import Pool, build_pools
from netapp_operator.spec import NetAppSpec, parse

Key = tuple[str | None, str]

# What placement and status read of each kind; the rest of an object (managedFields above all, and kopf's copy of
# the last spec it handled) is dropped on the way in, so thousands of NetApps fit (bench/operator_bench.py: RSS).
_KEPT_METADATA = ("name", "namespace", "uid", "generation", "labels", "resourceVersion", "deletionTimestamp")
_KEPT_SPEC: dict[str, tuple[str, ...] | None] = {"Deployment": ("replicas",), "Service": ("type", "ports")}


def slim(body: Mapping[str, Any], kind: str) -> dict[str, Any]:
    """The parts of a watched object the operator reads: its identity and status, its spec where it is ours to
    parse (a NetApp's), only the fields placement and status read of a child's."""
    meta = body.get("metadata") or {}
    kept: dict[str, Any] = {k: v for k, v in body.items() if k not in ("metadata", "spec")}
    kept["metadata"] = {k: meta[k] for k in _KEPT_METADATA if k in meta}
    spec = body.get("spec")
    if spec is not None:
        fields = _KEPT_SPEC.get(kind)
        kept["spec"] = spec if fields is None else {k: spec[k] for k in fields if k in spec}
    return kept


class Cache:
    def __init__(self) -> None:
        self.nodes: dict[str, Mapping[str, Any]] = {}
        self.nodepools: dict[str, Mapping[str, Any]] = {}
        self.netapps: dict[Key, Mapping[str, Any]] = {}
        self.specs: dict[Key, NetAppSpec] = {}  # each NetApp's spec, parsed once per event
        self.deployments: dict[Key, Mapping[str, Any]] = {}
        self.services: dict[Key, Mapping[str, Any]] = {}
        self._pools: dict[str, Pool] | None = None

    def _store(self, store: dict, key: Any, body: Mapping[str, Any], deleted: bool) -> None:
        if deleted:
            store.pop(key, None)
        else:
            store[key] = body

    def on_node(self, body: Mapping[str, Any], deleted: bool) -> None:
        self._store(self.nodes, body["metadata"]["name"], body, deleted)
        self._pools = None

    def on_nodepool(self, body: Mapping[str, Any], deleted: bool) -> None:
        self._store(self.nodepools, body["metadata"]["name"], body, deleted)
        self._pools = None

    def on_netapp(self, body: Mapping[str, Any], deleted: bool) -> None:
        body = slim(body, "NetApp")
        meta = body["metadata"]
        key = (meta.get("namespace"), meta["name"])
        self._store(self.netapps, key, body, deleted)
        self._store(self.specs, key, None if deleted else parse(body.get("spec")), deleted)

    def spec_of(self, body: Mapping[str, Any]) -> NetAppSpec:
        """The parsed spec of a NetApp: the cached parse when `body` is the cached object, else a new one."""
        meta = body["metadata"]
        key = (meta.get("namespace"), meta["name"])
        return self.specs[key] if self.netapps.get(key) is body else parse(body.get("spec"))

    def on_deployment(self, body: Mapping[str, Any], deleted: bool) -> None:
        body = slim(body, "Deployment")
        meta = body["metadata"]
        self._store(self.deployments, (meta.get("namespace"), meta["name"]), body, deleted)

    def on_service(self, body: Mapping[str, Any], deleted: bool) -> None:
        body = slim(body, "Service")
        meta = body["metadata"]
        self._store(self.services, (meta.get("namespace"), meta["name"]), body, deleted)

    def pools(self) -> dict[str, Pool]:
        """Pools with their node health; recomputed only after a node or pool event."""
        if self._pools is None:
            self._pools = build_pools(self.nodepools.values(), self.nodes.values())
        return self._pools
