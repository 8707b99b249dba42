"""What the operator has seen on its watches: nodes, pools, netapps and their children (no I/O).

Placement and status checks read from here, so the periodic check costs no API call unless something changed.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from netapp_operator.constants import ANNOTATION_MODEL, ANNOTATION_TRACEPARENT, ANNOTATION_WAKE
from netapp_operator.placement import Pool, build_pools
from netapp_operator.spec import NetAppSpec, parse

Key = tuple[str | None, str]

# What placement and status read of each kind; the rest of an object (managedFields above all, and kopf's copy of
# the last spec it handled) is dropped on the way in, so thousands of NetApps fit (bench/operator_bench.py: RSS).
_KEPT_METADATA = ("name", "namespace", "uid", "generation", "labels", "resourceVersion", "deletionTimestamp")
_KEPT_ANNOTATIONS = (ANNOTATION_TRACEPARENT, ANNOTATION_MODEL, ANNOTATION_WAKE)
_KEPT_SPEC: dict[str, tuple[str, ...] | None] = {"Deployment": ("replicas",), "Service": ("type", "ports", "clusterIP")}


def slim(body: Mapping[str, Any], kind: str) -> dict[str, Any]:
    """The parts of a watched object the operator reads: its identity and status, its spec where it is ours to
    parse (a NetApp's), only the fields placement and status read of a child's."""
    meta = body.get("metadata") or {}
    kept: dict[str, Any] = {k: v for k, v in body.items() if k not in ("metadata", "spec")}
    kept["metadata"] = {k: meta[k] for k in _KEPT_METADATA if k in meta}
    # The annotations read: a NetApp's traceparent (its reconciles join that trace, netapp_operator.tracing) and a
    # Deployment's model (a promoted rollout renders it again, netapp_operator.rollouts), a NetApp's wake (idle).
    annotations = {k: v for k, v in (meta.get("annotations") or {}).items() if k in _KEPT_ANNOTATIONS}
    if annotations:
        kept["metadata"]["annotations"] = annotations
    spec = body.get("spec")
    if spec is not None:
        fields = _KEPT_SPEC.get(kind)
        kept["spec"] = spec if fields is None else {k: spec[k] for k in fields if k in spec}
    return kept


def _older(body: Mapping[str, Any], cached: Mapping[str, Any] | None) -> bool:
    """Whether `body` is an older version of the same object than `cached`: a watch event still on its way after
    the operator's own write fed the cache must not put the old status back (it would be synced again). Compared as
    numbers where both are (etcd revisions, as every API server serves them); an opaque version is always newer."""
    if cached is None:
        return False
    new, old = (b["metadata"].get("resourceVersion") or "" for b in (body, cached))
    same = body["metadata"].get("uid") == cached["metadata"].get("uid")
    return same and new.isdigit() and old.isdigit() and int(new) < int(old)


class Cache:
    def __init__(self) -> None:
        self.nodes: dict[str, Mapping[str, Any]] = {}
        self.nodepools: dict[str, Mapping[str, Any]] = {}
        self.netapps: dict[Key, Mapping[str, Any]] = {}
        self.specs: dict[Key, NetAppSpec] = {}  # each NetApp's spec, parsed once per event
        self.deployments: dict[Key, Mapping[str, Any]] = {}
        self.services: dict[Key, Mapping[str, Any]] = {}
        self._pools: dict[str, Pool] | None = None

    def _store(self, store: dict, key: Any, body: Any, deleted: bool) -> None:
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
        if not deleted and _older(body, self.netapps.get(key)):
            return
        self._store(self.netapps, key, body, deleted)
        self._store(self.specs, key, None if deleted else parse(body.get("spec")), deleted)

    def spec_of(self, body: Mapping[str, Any]) -> NetAppSpec:
        """The parsed spec of a NetApp: the cached parse when `body` is the cached object, else a new one."""
        meta = body["metadata"]
        key = (meta.get("namespace"), meta["name"])
        return self.specs[key] if self.netapps.get(key) is body else parse(body.get("spec"))

    def on_deployment(self, body: Mapping[str, Any], deleted: bool) -> None:
        self._on_child(self.deployments, "Deployment", body, deleted)

    def on_service(self, body: Mapping[str, Any], deleted: bool) -> None:
        self._on_child(self.services, "Service", body, deleted)

    def _on_child(self, store: dict, kind: str, body: Mapping[str, Any], deleted: bool) -> None:
        body = slim(body, kind)
        meta = body["metadata"]
        key = (meta.get("namespace"), meta["name"])
        if deleted or not _older(body, store.get(key)):
            self._store(store, key, body, deleted)

    def relisted(self, kind: str, namespace: str | None, items: list[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
        """A new listing of Deployments or Services (in `namespace`, or all) replaces what the cache held there.
        Returns what changed: the objects new or changed since, and those gone (deleted while no watch was open)."""
        store = self.deployments if kind == "Deployment" else self.services
        before = {k: v for k, v in store.items() if namespace is None or k[0] == namespace}
        for k in before:
            del store[k]
        changed: list[Mapping[str, Any]] = []
        for item in items:
            body = slim(item, kind)
            key = (body["metadata"].get("namespace"), body["metadata"]["name"])
            store[key] = body
            was = before.pop(key, None)
            if was is None or was["metadata"].get("resourceVersion") != body["metadata"].get("resourceVersion"):
                changed.append(body)
        return changed + list(before.values())

    def pools(self) -> dict[str, Pool]:
        """Pools with their node health; recomputed only after a node or pool event."""
        if self._pools is None:
            self._pools = build_pools(self.nodepools.values(), self.nodes.values())
        return self._pools
