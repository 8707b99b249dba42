"""The operator's watches of its own children (Deployments, Services): the kube client's list-then-watch into the
cache, each change queueing the NetApp that owns the child.

Not kopf's: a NetApp's children are thousands of objects whose events only feed the cache, and kopf keeps a
memory, a worker and three loggers per object and event (docs/operator.md#at-fleet-scale).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from netapp_operator.cache import Cache, Key
from netapp_operator.constants import LABEL_INSTANCE, LABEL_MANAGED_BY, OPERATOR_MANAGER
from netapp_operator.kube import Kube
from netapp_operator.workqueue import cancel

logger = logging.getLogger(__name__)
MANAGED = {LABEL_MANAGED_BY: OPERATOR_MANAGER}
WATCHED_CHILDREN = ("Deployment", "Service")  # what placement and status read of a NetApp's children


def owner(child: Mapping[str, Any]) -> Key | None:
    """The NetApp a child of ours belongs to (by its instance label)."""
    meta = child.get("metadata") or {}
    instance = (meta.get("labels") or {}).get(LABEL_INSTANCE)
    return (meta.get("namespace"), instance) if instance else None


class ChildWatches:
    """One watch per child kind and namespace (all namespaces: one); `changed(key)` for each NetApp whose child
    changed. `primed` waits for every watch's first listing (the cache then holds every child)."""

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
                self._tasks.append(
                    asyncio.create_task(self._follow(kind, namespace, listed), name=f"netapp-operator-watch-{kind}")
                )

    async def primed(self) -> None:
        await asyncio.gather(*(listed.wait() for listed in self._listed))

    async def stop(self) -> None:
        await cancel(self._tasks)
        self._tasks = []

    async def _follow(self, kind: str, namespace: str | None, listed: asyncio.Event) -> None:
        store = self._cache.on_deployment if kind == "Deployment" else self._cache.on_service
        while True:
            try:
                async for type_, obj in self._kube.watch(kind, namespace, labels=MANAGED, timeout_s=self._timeout_s):
                    if type_ == "LISTED":
                        self._report(self._cache.relisted(kind, namespace, obj))
                        listed.set()
                    else:
                        store(obj, deleted=type_ == "DELETED")
                        self._report([obj])
            except Exception:  # a bug in handling one event must not end the watch for good
                logger.exception("the %s watch failed; it starts over", kind)
                await asyncio.sleep(1)

    def _report(self, children: Iterable[Mapping[str, Any]]) -> None:
        for child in children:
            key = owner(child)
            if key is not None:
                self._changed(key)
