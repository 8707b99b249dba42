"""The kubernetes backend: each instance is a `NetApp` custom resource that the operator reconciles.

The middleware only creates and deletes NetApps and follows their status through one list-then-watch on the
namespace; the operator places them and writes `status.phase`, `url` and `pool` (a failover changes the last two).
Every call goes through the one async Kubernetes client, `netapp_operator.kube` (its list-then-watch included).
The operator drives model rollouts and writes `status.rollout`; the watch hands it to the `rollout_sink`, and a
NetApp's deletion too, so its rollout's verdict (or why there is none) is kept once the NetApp is gone.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import secrets
from typing import Any

from netapp_operator.constants import (
    ANNOTATION_APP,
    ANNOTATION_CLAIMS,
    ANNOTATION_PLACEMENT,
    ANNOTATION_WAKE,
    API_VERSION,
    LABEL_APP,
    LABEL_MANAGED_BY,
    LABEL_SHARED,
    MIDDLEWARE_MANAGER,
    NETAPP_KIND,
)
from netapp_operator.events import event_manifest
from netapp_operator.kube import Kube
from netapp_operator.rollout_status import as_netapp_state
from netapp_operator.spec import parse

from .base import PENDING, Claim, InstanceState, Recovered, RolloutSink, StateCallback

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
    """NetApps in one namespace of the cluster that `kube` reaches (the backend owns the client and closes it)."""

    name = "kubernetes"

    def __init__(self, namespace: str, kube: Kube, *, watch_read_timeout_s: float = 60.0) -> None:
        self.namespace = namespace
        self.kube = kube
        self._read_timeout_s = watch_read_timeout_s
        self._task: asyncio.Task[None] | None = None
        self._report: StateCallback = lambda name, state: None
        # NetApps the API server has shown us and we did not delete: one missing from a fresh listing was deleted
        # while no watch was open.
        self._seen: set[str] = set()
        self._instance = os.environ.get("HOSTNAME", MIDDLEWARE_MANAGER)  # the reporting instance of our Events
        # Told each NetApp's status.rollout and its deletion (model_rollouts.ModelRollouts sets itself)
        self.rollout_sink: RolloutSink | None = None

    async def start(self, report: StateCallback) -> list[Recovered]:
        self._report = report
        # List before watching: the registry must know the survivors before the watch reports on them.
        items = await self.kube.list(NETAPP_KIND, self.namespace)
        self._seen = {item["metadata"]["name"] for item in items}
        self._task = asyncio.get_running_loop().create_task(self._follow(), name="netapp-watch")
        return [r for r in map(recovered_from, items) if r is not None]

    def refuse(self, spec: dict[str, Any]) -> str | None:
        """What the operator would refuse in `spec` (its first problem, netapp_operator.spec), None when nothing."""
        problems = parse(spec).problems
        return problems[0] if problems else None

    async def create(
        self,
        name: str,
        app: str,
        placement: str | None,
        spec: dict[str, Any],
        labels: dict[str, str],
        annotations: dict[str, str] | None = None,
    ) -> None:
        annotations = {**(annotations or {}), ANNOTATION_APP: app, ANNOTATION_PLACEMENT: placement or ""}
        body = netapp_manifest(
            name, self.namespace, spec, {**labels, LABEL_MANAGED_BY: MIDDLEWARE_MANAGER}, annotations
        )
        await self.kube.apply(body)
        log.info("created NetApp %s/%s", self.namespace, name)

    async def record(self, name: str, claims: list[Claim]) -> None:
        # A merge patch of the one annotation: applying it alone would drop the spec this manager applied.
        patch = {"metadata": {"annotations": {ANNOTATION_CLAIMS: claims_annotation(claims)}}}
        await self.kube.merge_patch(NETAPP_KIND, self.namespace, name, patch)

    async def wake(self, name: str) -> None:
        """A new value in the NetApp's wake annotation: the operator scales a sleeping one up again (phase Idle ->
        Deploying -> Ready, through the watch) and restarts the quiet clock of an awake one (netapp_operator.idle)."""
        patch = {"metadata": {"annotations": {ANNOTATION_WAKE: secrets.token_hex(8)}}}
        await self.kube.merge_patch(NETAPP_KIND, self.namespace, name, patch)

    async def delete(self, name: str) -> None:
        self._seen.discard(name)
        self._ended(name)
        await self.kube.delete(NETAPP_KIND, self.namespace, name)  # already gone is what we wanted
        log.info("deleted NetApp %s/%s", self.namespace, name)

    async def announce(self, name: str, type_: str, reason: str, message: str) -> None:
        """A Kubernetes Event on the NetApp (`kubectl describe netapp NAME` lists it)."""
        try:
            netapp = await self.kube.get(NETAPP_KIND, self.namespace, name)
            if netapp is None:
                return
            await self.kube.create(
                event_manifest(netapp, type_, reason, message, component=MIDDLEWARE_MANAGER, instance=self._instance)
            )
        except Exception as exc:  # an Event is advice: the move itself went on
            log.warning("could not post event %s for NetApp %s: %s", reason, name, exc)

    async def close(self) -> None:
        # NetApps outlive the middleware: they belong to the cluster, not to this process.
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        await self.kube.close()

    async def _follow(self) -> None:
        """The kube client's list-then-watch: each listing resyncs, each event reports one NetApp."""
        async for kind, obj in self.kube.watch(NETAPP_KIND, self.namespace, timeout_s=self._read_timeout_s):
            if kind == "LISTED":
                self._resync(obj)
            else:
                self._apply(obj, deleted=kind == "DELETED")

    def _apply(self, netapp: dict[str, Any], deleted: bool) -> None:
        name = (netapp.get("metadata") or {}).get("name")
        if not name:
            return
        if deleted:
            self._seen.discard(name)
            self._ended(name)
            self._report(name, InstanceState("Failed", message=GONE))
        else:
            self._seen.add(name)
            self._observe(name, netapp)
            self._report(name, state_of(netapp))

    def _observe(self, name: str, netapp: dict[str, Any]) -> None:
        rollout = (netapp.get("status") or {}).get("rollout")
        if self.rollout_sink is not None and isinstance(rollout, dict) and rollout:
            app = ((netapp.get("metadata") or {}).get("annotations") or {}).get(ANNOTATION_APP) or name
            self.rollout_sink.observe(name, app, as_netapp_state(rollout))

    def _ended(self, name: str) -> None:
        if self.rollout_sink is not None:
            self.rollout_sink.ended(name)

    def _resync(self, items: list[dict[str, Any]]) -> None:
        present = {(item.get("metadata") or {}).get("name") for item in items}
        for name in self._seen - present:  # deleted during the gap: its DELETED event was never ours
            self._seen.discard(name)
            self._ended(name)
            self._report(name, InstanceState("Failed", message=GONE))
        for item in items:
            self._apply(item, deleted=False)
