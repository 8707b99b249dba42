"""kopf handlers, all registered here on one registry; each is a line or two over `Reconciler` and `Cache`."""

from __future__ import annotations

import asyncio
import contextlib
import copy
import dataclasses
import logging
from typing import Any

import kopf

from netapp_operator.cache import Cache
from netapp_operator.config import OperatorConfig
from netapp_operator.constants import (
    GROUP,
    LABEL_INSTANCE,
    LABEL_MANAGED_BY,
    NETAPP_PLURAL,
    NODEPOOL_PLURAL,
    OPERATOR_MANAGER,
    VERSION,
)
from netapp_operator.kube import ApiError, Kube, environment_login, login_from_info
from netapp_operator.reconcile import Reconciler

logger = logging.getLogger(__name__)
MANAGED = {LABEL_MANAGED_BY: OPERATOR_MANAGER}


@dataclasses.dataclass
class Runtime:
    """What one running operator holds; tests reach into it to wait for the watches."""

    config: OperatorConfig
    cache: Cache
    reconciler: Reconciler | None = None
    task: asyncio.Task[None] | None = None
    checks: int = 0  # completed periodic passes


def _connection_info(cfg: Any) -> kopf.ConnectionInfo:
    """kopf's login from the client's: one reader of kubeconfigs (exec plugins included) and service accounts."""
    scheme, _, token = str(cfg.api_key.get("BearerToken") or "").partition(" ")
    return kopf.ConnectionInfo(
        server=cfg.host,
        ca_path=cfg.ssl_ca_cert,
        insecure=not cfg.verify_ssl,
        scheme=scheme or None,
        token=token or None,
        username=cfg.username or None,
        password=cfg.password or None,
        certificate_path=cfg.cert_file,
        private_key_path=cfg.key_file,
    )


def register(
    registry: kopf.OperatorRegistry, config: OperatorConfig, connection: kopf.ConnectionInfo | None = None
) -> Runtime:
    """Register every handler of the operator on `registry`; `connection` bypasses the login (tests)."""
    rt = Runtime(config=config, cache=Cache())
    netapps = dict(group=GROUP, version=VERSION, plural=NETAPP_PLURAL)
    nodepools = dict(group=GROUP, version=VERSION, plural=NODEPOOL_PLURAL)

    @kopf.on.login(registry=registry)
    async def login(**_: Any) -> kopf.ConnectionInfo:
        return connection if connection is not None else _connection_info(await environment_login())

    @kopf.on.startup(registry=registry)
    async def startup(settings: kopf.OperatorSettings, logger: Any, **_: Any) -> None:
        settings.watching.server_timeout = config.watch_server_timeout
        settings.watching.client_timeout = config.watch_client_timeout
        settings.watching.connect_timeout = config.watch_connect_timeout
        # kopf's own bookkeeping in annotations under our group, so the status schema can stay strict.
        settings.persistence.progress_storage = kopf.AnnotationsProgressStorage(prefix=GROUP)
        settings.persistence.diffbase_storage = kopf.AnnotationsDiffBaseStorage(
            prefix=GROUP, key="last-handled-configuration"
        )
        # Handler log lines become Events only for warnings; the reconciler posts the Events users need.
        settings.posting.level = logging.WARNING

        async def relogin() -> Any:
            return await login_from_info(connection) if connection is not None else await environment_login()

        kube = Kube(relogin, manager=OPERATOR_MANAGER)
        rt.reconciler = Reconciler(kube, rt.cache, config)
        await _prime(rt, kube)
        rt.task = asyncio.create_task(_periodic(rt), name="netapp-operator-checks")

    @kopf.on.cleanup(registry=registry)
    async def cleanup(**_: Any) -> None:
        if rt.task is not None:
            rt.task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await rt.task
        if rt.reconciler is not None:
            await rt.reconciler.kube.close()

    # --- what the cache watches --------------------------------------------------------------------------
    # Coroutines although they do no I/O: kopf runs a plain function in a worker thread, a thread hop per event.

    @kopf.on.event("v1", "nodes", registry=registry)
    async def node_event(event: dict[str, Any], **_: Any) -> None:
        rt.cache.on_node(event["object"], deleted=event.get("type") == "DELETED")

    @kopf.on.event(**nodepools, registry=registry)
    async def nodepool_event(event: dict[str, Any], **_: Any) -> None:
        rt.cache.on_nodepool(event["object"], deleted=event.get("type") == "DELETED")

    @kopf.on.event(**netapps, registry=registry)
    async def netapp_event(event: dict[str, Any], **_: Any) -> None:
        deleted = event.get("type") == "DELETED"
        rt.cache.on_netapp(event["object"], deleted=deleted)

    @kopf.on.event("apps", "v1", "deployments", labels=MANAGED, registry=registry)
    async def deployment_event(event: dict[str, Any], **_: Any) -> None:
        rt.cache.on_deployment(event["object"], deleted=event.get("type") == "DELETED")
        await _check_owner(rt, event["object"])

    @kopf.on.event("v1", "services", labels=MANAGED, registry=registry)
    async def service_event(event: dict[str, Any], **_: Any) -> None:
        rt.cache.on_service(event["object"], deleted=event.get("type") == "DELETED")
        await _check_owner(rt, event["object"])

    # --- the NetApp itself -------------------------------------------------------------------------------

    @kopf.on.create(**netapps, registry=registry, backoff=5)
    async def netapp_created(body: kopf.Body, namespace: str, name: str, **_: Any) -> None:
        await created(rt, namespace, name, _plain(body))

    @kopf.on.update(**netapps, registry=registry, backoff=5)
    async def netapp_changed(namespace: str, name: str, **_: Any) -> None:
        await _sync(rt, namespace, name, apply=True)

    @kopf.on.resume(**netapps, registry=registry, backoff=5)
    async def netapp_resumed(namespace: str, name: str, **_: Any) -> None:
        # A restarted operator: a move may have stopped between the new children and the removal of the old.
        await _sync(rt, namespace, name, apply=True, sweep=True)

    return rt


async def created(rt: Runtime, namespace: str, name: str, body: dict[str, Any]) -> None:
    """A NetApp kopf has not handled yet. Level-triggered: kopf calls this again for a NetApp whose own patch it
    has not seen within its consistency timeout (a burst), and one already placed with its children then costs no
    request."""
    rt.cache.on_netapp(body, deleted=False)
    await _sync(rt, namespace, name, body=body)


def _plain(body: kopf.Body) -> dict[str, Any]:
    return copy.deepcopy(dict(body))


async def _sync(
    rt: Runtime,
    namespace: str,
    name: str,
    body: dict[str, Any] | None = None,
    apply: bool = False,
    sweep: bool = False,
) -> None:
    assert rt.reconciler is not None
    try:
        await rt.reconciler.sync(namespace, name, body=body, apply=apply, sweep=sweep)
    except ApiError as e:
        # Retried by kopf with backoff for this NetApp only; the others carry on.
        raise kopf.TemporaryError(f"API server error: {e.status} {e.reason}", delay=5) from e


async def _check_owner(rt: Runtime, child: dict[str, Any]) -> None:
    if rt.reconciler is None:
        return
    meta = child.get("metadata", {})
    instance = (meta.get("labels") or {}).get(LABEL_INSTANCE)
    if instance:
        try:
            await rt.reconciler.check(meta.get("namespace"), instance)
        except ApiError as e:  # the periodic pass retries
            logger.warning("status refresh of NetApp %s/%s failed: %s", meta.get("namespace"), instance, e)


async def _prime(rt: Runtime, kube: Kube) -> None:
    """Fill the cache before any NetApp handler runs (startup handlers run before the watches start): otherwise
    the resume handlers of a restarted operator would see no pools and mark every NetApp Pending."""
    for node in await kube.list("Node"):
        rt.cache.on_node(node, deleted=False)
    try:
        pools = await kube.list("NodePool")
    except ApiError as e:
        if e.status == 404:
            raise kopf.PermanentError(
                "the NodePool CRD is not installed: kubectl apply -f manifests/00-crds.yaml"
            ) from e
        raise
    for pool in pools:
        rt.cache.on_nodepool(pool, deleted=False)
    for namespace in rt.config.namespaces or (None,):
        for dep in await kube.list("Deployment", namespace, MANAGED):
            rt.cache.on_deployment(dep, deleted=False)
        for svc in await kube.list("Service", namespace, MANAGED):
            rt.cache.on_service(svc, deleted=False)


async def _periodic(rt: Runtime) -> None:
    assert rt.reconciler is not None
    while True:
        await asyncio.sleep(rt.config.check_interval_seconds)
        try:
            await rt.reconciler.check_all()
        except Exception:
            logger.exception("periodic placement check failed")
        rt.checks += 1
