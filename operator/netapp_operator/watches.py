"""The operator's own watches: the NetApps, and their children that the status reads (Deployments, Services). The
kube client's list-then-watch feeds the cache, and each change queues the NetApp it concerns.

Not kopf's: a NetApp's events only feed the cache and queue it, and kopf spends far more on an event than that
(its causes, diffs, per-object memory, worker task and loggers: 16 % of the operator's CPU in a burst of 4,000
NetApps, bench/operator_bench.py), and the children are thousands more objects (docs/operator.md#at-fleet-scale).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from netapp_operator.cache import Cache, Key
from netapp_operator.constants import LABEL_INSTANCE, LABEL_MANAGED_BY, NETAPP_KIND, OPERATOR_MANAGER
from netapp_operator.kube import Kube
from netapp_operator.workqueue import cancel

logger = logging.getLogger(__name__)
MANAGED = {LABEL_MANAGED_BY: OPERATOR_MANAGER}
WATCHED_CHILDREN = ("Deployment", "Service")  # what placement and status read of a NetApp's children
Seen = Callable[[Mapping[str, Any], bool], None]  # a NetApp's body, and whether it was deleted


def owner(child: Mapping[str, Any]) -> Key | None:
    """The NetApp a child of ours belongs to (by its instance label)."""
    meta = child.get("metadata") or {}
    instance = (meta.get("labels") or {}).get(LABEL_INSTANCE)
    return (meta.get("namespace"), instance) if instance else None


def gone_netapps(cache: Cache, namespace: str | None, items: Iterable[Mapping[str, Any]]) -> list[Key]:
    """The NetApps the cache holds (in `namespace`, or all) that a new listing no longer has: deleted while no
    watch was open."""
    listed = {(i["metadata"].get("namespace"), i["metadata"]["name"]) for i in items}
    return [key for key in cache.netapps if (namespace is None or key[0] == namespace) and key not in listed]


class Watches:
    """One watch per kind and namespace (all namespaces: one). Children: `changed(key)` for each NetApp whose
    child changed; `primed` waits for every child watch's first listing (the cache then holds every child).
    NetApps (`start_netapps`): `seen(body, deleted)` for each, listed or changed."""

    def __init__(self, kube: Kube, cache: Cache, changed: Callable[[Key], None], timeout_s: float) -> None:
        self._kube = kube
        self._cache = cache
        self._changed = changed
        self._timeout_s = timeout_s
        self._tasks: list[asyncio.Task[None]] = []
        self._listed: list[asyncio.Event] = []

    def start(self, namespaces: Iterable[str | None]) -> None:
        for namespace in namespaces:
            for kind in WATCHED_CHILDREN:
                listed = asyncio.Event()
                self._listed.append(listed)
                self._spawn(self._follow_children(kind, namespace, listed), kind)

    def start_netapps(self, namespaces: Iterable[str | None], seen: Seen) -> None:
        for namespace in namespaces:
            self._spawn(self._follow_netapps(namespace, seen), NETAPP_KIND)

    async def primed(self) -> None:
        await asyncio.gather(*(listed.wait() for listed in self._listed))

    async def stop(self) -> None:
        await cancel(self._tasks)
        self._tasks = []

    def _spawn(self, follow: Any, kind: str) -> None:
        self._tasks.append(asyncio.create_task(follow, name=f"netapp-operator-watch-{kind}"))

    async def _follow(
        self,
        kind: str,
        namespace: str | None,
        labels: Mapping[str, str] | None,
        on_listed: Callable[[list[Any]], None],
        on_event: Callable[[str, Any], None],
    ) -> None:
        while True:
            try:
                async for type_, obj in self._kube.watch(kind, namespace, labels=labels, timeout_s=self._timeout_s):
                    if type_ == "LISTED":
                        on_listed(obj)
                    else:
                        on_event(type_, obj)
            except Exception:  # a bug in handling one event must not end the watch for good
                logger.exception("the %s watch failed; it starts over", kind)
                await asyncio.sleep(1)

    async def _follow_children(self, kind: str, namespace: str | None, listed: asyncio.Event) -> None:
        store = self._cache.on_deployment if kind == "Deployment" else self._cache.on_service

        def on_listed(items: list[Any]) -> None:
            self._report(self._cache.relisted(kind, namespace, items))
            listed.set()

        def on_event(type_: str, obj: Any) -> None:
            store(obj, deleted=type_ == "DELETED")
            self._report([obj])

        await self._follow(kind, namespace, MANAGED, on_listed, on_event)

    async def _follow_netapps(self, namespace: str | None, seen: Seen) -> None:
        def on_listed(items: list[Any]) -> None:
            for ns, name in gone_netapps(self._cache, namespace, items):
                seen({"metadata": {"namespace": ns, "name": name}}, True)
            for item in items:
                seen(item, False)

        await self._follow(NETAPP_KIND, namespace, None, on_listed, lambda type_, obj: seen(obj, type_ == "DELETED"))

    def _report(self, children: Iterable[Mapping[str, Any]]) -> None:
        for child in children:
            key = owner(child)
            if key is not None:
                self._changed(key)
