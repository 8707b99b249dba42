"""The kubernetes backend: each instance is a `NetApp` custom resource that the operator reconciles.

The middleware only creates and deletes NetApps and follows their status through one list-then-watch on the
namespace; the operator places them and writes `status.phase`, `url` and `pool` (a failover changes the last two).
The `kubernetes` client is synchronous, so calls run in worker threads and the watch in a thread of its own.
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
from typing import Any

from netapp_operator.constants import (
    ANNOTATION_APP,
    ANNOTATION_CLAIMS,
    ANNOTATION_PLACEMENT,
    API_VERSION,
    GROUP,
    LABEL_APP,
    LABEL_MANAGED_BY,
    LABEL_SHARED,
    MIDDLEWARE_MANAGER,
    NETAPP_KIND,
    NETAPP_PLURAL,
    VERSION,
)

from .base import PENDING, Claim, InstanceState, Recovered, StateCallback

log = logging.getLogger(__name__)

GONE = "the NetApp was deleted outside the middleware"


def netapp_manifest(
    name: str, namespace: str, spec: dict[str, Any], labels: dict[str, str], annotations: dict[str, str] | None = None
) -> dict[str, Any]:
    return {
        "apiVersion": API_VERSION,
        "kind": NETAPP_KIND,
        "metadata": {
            "name": name,
            "namespace": namespace,
            "labels": dict(labels),
            "annotations": dict(annotations or {}),
        },
        "spec": spec,
    }


def claims_annotation(claims: list[Claim]) -> str:
    return json.dumps(
        {
            c.deployment_id: {
                "robot": c.robot_id,
                "placement": c.placement,
                "reuse": c.reuse,
                "createdAt": c.created_at,
                "meta": c.meta,
            }
            for c in claims
        },
        sort_keys=True,
    )


def recovered_from(netapp: dict[str, Any]) -> Recovered | None:
    """A NetApp this middleware made -> what it needs to take it back; None for anyone else's NetApp."""
    meta = netapp.get("metadata") or {}
    labels, annotations = meta.get("labels") or {}, meta.get("annotations") or {}
    if labels.get(LABEL_MANAGED_BY) != MIDDLEWARE_MANAGER or meta.get("deletionTimestamp"):
        return None
    try:
        raw = json.loads(annotations.get(ANNOTATION_CLAIMS) or "{}")
        claims = tuple(
            Claim(
                deployment_id=str(k),
                robot_id=str(v["robot"]),
                placement=v.get("placement"),
                reuse=bool(v.get("reuse")),
                created_at=float(v.get("createdAt", 0.0)),
                meta=dict(v.get("meta") or {}),
            )
            for k, v in raw.items()
        )
    except (ValueError, KeyError, TypeError, AttributeError):
        log.warning("NetApp %s: unreadable %s annotation; treating it as unused", meta.get("name"), ANNOTATION_CLAIMS)
        claims = ()
    return Recovered(
        name=str(meta["name"]),
        app=str(annotations.get(ANNOTATION_APP) or labels.get(LABEL_APP, "")),
        placement=annotations.get(ANNOTATION_PLACEMENT) or None,
        shared=labels.get(LABEL_SHARED) == "true",
        state=state_of(netapp),
        claims=claims,
    )


def state_of(netapp: dict[str, Any]) -> InstanceState:
    """A NetApp object -> the instance state a robot sees (the message from the most telling condition)."""
    status = netapp.get("status") or {}
    phase = status.get("phase") or PENDING
    conditions = [c for c in status.get("conditions") or [] if isinstance(c, dict)]
    # A condition that is not True explains why the NetApp is not Ready; else Ready's own message.
    failing = [c for c in conditions if str(c.get("status")) != "True"]
    chosen = failing[0] if failing else next((c for c in conditions if c.get("type") == "Ready"), None)
    message = ""
    if chosen is not None:
        message = ": ".join(str(x) for x in (chosen.get("type"), chosen.get("reason"), chosen.get("message")) if x)
    elif phase == PENDING:
        message = "waiting for the operator"
    if (netapp.get("metadata") or {}).get("deletionTimestamp"):
        message = f"being deleted; {message}".rstrip("; ")
    return InstanceState(phase=str(phase), url=status.get("url"), pool=status.get("pool"), message=message)


class KubernetesBackend:
    """NetApps in one namespace of the cluster that the given ApiClient reaches."""

    name = "kubernetes"

    def __init__(self, namespace: str, api_client: Any = None, *, watch_read_timeout_s: float = 60.0) -> None:
        from kubernetes import client

        self.namespace = namespace
        self.api = client.CustomObjectsApi(api_client)
        self._read_timeout_s = watch_read_timeout_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._watcher: Any = None
        self._report: StateCallback = lambda name, state: None
        self._loop: asyncio.AbstractEventLoop | None = None
        # NetApps the API server has shown us and we did not delete (touched on the event loop only): one missing
        # from a fresh listing was deleted while no watch was open.
        self._seen: set[str] = set()

    async def start(self, report: StateCallback) -> list[Recovered]:
        self._report = report
        self._loop = asyncio.get_running_loop()
        # List before watching: the registry must know the survivors before the watch reports on them.
        listing = await asyncio.to_thread(
            self.api.list_namespaced_custom_object, GROUP, VERSION, self.namespace, NETAPP_PLURAL
        )
        items = listing.get("items") or []
        self._seen = {item["metadata"]["name"] for item in items}
        self._thread = threading.Thread(target=self._watch, name="netapp-watch", daemon=True)
        self._thread.start()
        return [r for r in map(recovered_from, items) if r is not None]

    async def create(
        self, name: str, app: str, placement: str | None, spec: dict[str, Any], labels: dict[str, str]
    ) -> None:
        annotations = {ANNOTATION_APP: app, ANNOTATION_PLACEMENT: placement or ""}
        body = netapp_manifest(
            name, self.namespace, spec, {**labels, LABEL_MANAGED_BY: MIDDLEWARE_MANAGER}, annotations
        )
        await asyncio.to_thread(
            self.api.create_namespaced_custom_object, GROUP, VERSION, self.namespace, NETAPP_PLURAL, body
        )
        log.info("created NetApp %s/%s", self.namespace, name)

    async def record(self, name: str, claims: list[Claim]) -> None:
        patch = {"metadata": {"annotations": {ANNOTATION_CLAIMS: claims_annotation(claims)}}}
        # Explicitly a merge patch: some client versions default to a JSON patch, which a dict is not.
        await asyncio.to_thread(
            self.api.patch_namespaced_custom_object,
            GROUP,
            VERSION,
            self.namespace,
            NETAPP_PLURAL,
            name,
            patch,
            _content_type="application/merge-patch+json",
        )

    async def delete(self, name: str) -> None:
        from kubernetes.client.exceptions import ApiException

        self._seen.discard(name)
        try:
            await asyncio.to_thread(
                self.api.delete_namespaced_custom_object, GROUP, VERSION, self.namespace, NETAPP_PLURAL, name
            )
        except ApiException as exc:
            if exc.status != 404:  # already gone is what we wanted
                raise
        log.info("deleted NetApp %s/%s", self.namespace, name)

    async def close(self) -> None:
        # NetApps outlive the middleware: they belong to the cluster, not to this process.
        self._stop.set()
        if self._watcher is not None:
            self._watcher.stop()  # shuts the socket down, so the thread's blocked read returns now
        if self._thread is not None:
            await asyncio.to_thread(self._thread.join, 10)

    def _watch(self) -> None:
        """List, then watch from the listing's version; a watch that ends (quiet, or the server went away) starts
        over with a new listing, which also reveals NetApps deleted while no watch was open."""
        from kubernetes import watch

        assert self._loop is not None
        while not self._stop.is_set():
            try:
                listing = self.api.list_namespaced_custom_object(
                    GROUP, VERSION, self.namespace, NETAPP_PLURAL, _request_timeout=(5, self._read_timeout_s)
                )
                self._loop.call_soon_threadsafe(self._resync, listing.get("items") or [])
                self._watcher = watch.Watch()
                if self._stop.is_set():  # close() ran before this watcher existed
                    return
                stream = self._watcher.stream(
                    self.api.list_namespaced_custom_object,
                    GROUP,
                    VERSION,
                    self.namespace,
                    NETAPP_PLURAL,
                    resource_version=(listing.get("metadata") or {}).get("resourceVersion"),
                    # The server ends a quiet watch first; the client's read timeout is for a server that does not.
                    timeout_seconds=max(1, int(self._read_timeout_s * 0.8)),
                    _request_timeout=(5, self._read_timeout_s),
                )
                for event in stream:
                    if self._stop.is_set():
                        return
                    obj = event.get("object")
                    if event.get("type") == "ERROR" or not isinstance(obj, dict):
                        raise RuntimeError(f"watch error: {obj}")  # e.g. 410 Gone: list again
                    self._loop.call_soon_threadsafe(self._apply, obj, event.get("type") == "DELETED")
            except Exception as exc:  # a read timeout on a quiet watch, or the API server going away: re-watch
                if not self._stop.is_set():
                    log.debug("NetApp watch restarts: %s", exc)
                    self._stop.wait(0.5)

    def _apply(self, netapp: dict[str, Any], deleted: bool) -> None:
        name = (netapp.get("metadata") or {}).get("name")
        if not name:
            return
        if deleted:
            self._seen.discard(name)
            self._report(name, InstanceState("Failed", message=GONE))
        else:
            self._seen.add(name)
            self._report(name, state_of(netapp))

    def _resync(self, items: list[dict[str, Any]]) -> None:
        present = {(item.get("metadata") or {}).get("name") for item in items}
        for name in self._seen - present:  # deleted during the gap: its DELETED event was never ours
            self._seen.discard(name)
            self._report(name, InstanceState("Failed", message=GONE))
        for item in items:
            self._apply(item, deleted=False)
