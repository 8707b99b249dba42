"""kopf handlers, all registered here on one registry; each is a line or two over `Reconciler` and `Cache`."""

from __future__ import annotations

import asyncio
import dataclasses
import gc
import logging
from typing import Any

import kopf

from netapp.tracing import tracer_from_env
from netapp_operator import metrics
from netapp_operator.cache import Cache
from netapp_operator.config import OperatorConfig
from netapp_operator.constants import GROUP, NODEPOOL_PLURAL, OPERATOR_MANAGER, VERSION
from netapp_operator.idle_poll import IdlePoller
from netapp_operator.kube import ApiError, Kube, environment_login, login_from_info
from netapp_operator.prepull import PrePull
from netapp_operator.reconcile import Reconciler
from netapp_operator.rollout_poll import RolloutPoller
from netapp_operator.tracing import SERVICE_NAME
from netapp_operator.waker import Waker
from netapp_operator.watches import Watches
from netapp_operator.workqueue import WorkQueue, cancel

logger = logging.getLogger(__name__)


@dataclasses.dataclass
class Runtime:
    """What one running operator holds; tests reach into it to wait for the watches."""

    config: OperatorConfig
    cache: Cache
    reconciler: Reconciler | None = None
    queue: WorkQueue | None = None
    watches: Watches | None = None
    task: asyncio.Task[None] | None = None
    metrics: Any = None  # the /metrics server (an aiohttp runner) while it runs
    checks: int = 0  # completed periodic passes
    rollouts: RolloutPoller | None = None  # model rollouts, when the operator has a rollout token
    rollout_task: asyncio.Task[None] | None = None
    idle: IdlePoller | None = None  # scales idle NetApps to zero (spec.scaling.idleToZero)
    idle_task: asyncio.Task[None] | None = None
    prepull: PrePull | None = None  # NodePools' image pre-pull DaemonSets
    waker: Waker | None = None  # sleeping NetApps' Services' endpoint (--waker-ip)

    def changed(self, key: Any) -> None:
        """Something a NetApp depends on changed: reconcile it (once, however often this is called meanwhile)."""
        if self.queue is not None:
            self.queue.add(key)


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
    """Register every handler of the operator on `registry`; `connection` bypasses the login (tests).

    kopf runs the start-up, the clean-up and the nodes' and pools' event handlers. The NetApps are watched by the
    operator's own watch (`watches.Watches`): a NetApp's event feeds the cache and queues it for the operator's own
    workers, which reconcile it from the cache, level-triggered (docs/operator.md#at-fleet-scale). kopf's
    create/update handlers would cost a patch per NetApp (their progress annotation), and its event handlers most
    of kopf's per-event work."""
    rt = Runtime(config=config, cache=Cache())
    nodepools = dict(group=GROUP, version=VERSION, plural=NODEPOOL_PLURAL)

    @kopf.on.login(registry=registry)
    async def login(**_: Any) -> kopf.ConnectionInfo:
        return connection if connection is not None else _connection_info(await environment_login())

    @kopf.on.startup(registry=registry)
    async def startup(settings: kopf.OperatorSettings, logger: Any, **_: Any) -> None:
        settings.watching.server_timeout = config.watch_server_timeout
        settings.watching.client_timeout = config.watch_client_timeout
        settings.watching.connect_timeout = config.watch_connect_timeout
        # Handler log lines become Events only for warnings; the reconciler posts the Events users need.
        settings.posting.level = logging.WARNING
        if config.metrics_endpoint:
            rt.metrics = await metrics.serve(metrics.registry_for(rt.cache, lambda: rt.queue), config.metrics_endpoint)

        async def relogin() -> Any:
            return await login_from_info(connection) if connection is not None else await environment_login()

        kube = Kube(relogin, manager=OPERATOR_MANAGER)
        rt.reconciler = reconciler = Reconciler(kube, rt.cache, config, tracer_from_env(SERVICE_NAME))
        rt.prepull = PrePull(kube, config)
        if config.rollout_token:
            rt.rollouts = RolloutPoller(kube, config, reconciler.event)
        await _prime(rt, kube)
        rt.queue = WorkQueue(reconciler.reconcile, workers=config.reconcile_workers, expected=(ApiError,))
        # The children are in the cache before any NetApp is reconciled, and a restarted operator knows each
        # NetApp's children without listing them per NetApp; then the NetApps' watch queues every NetApp.
        namespaces = config.namespaces or (None,)
        rt.watches = Watches(kube, rt.cache, rt.changed, config.watch_client_timeout)
        rt.watches.start(namespaces)
        await rt.watches.primed()
        await reconciler.find_leftovers(namespaces)
        # What start-up made (the modules, kubernetes_asyncio's thousands of model classes, kopf, the primed cache)
        # lives as long as the operator: out of the cyclic collector, whose full passes would walk it all again each
        # time the objects made since grew by a quarter (bench/operator_bench.py: the collector was a third of the
        # operator's CPU in a burst of 3,000 NetApps, a tenth with this). Reference counting still frees it; the
        # garbage goes first, and the clean-up gives the rest back to the collector (an operator in a test process).
        gc.collect()
        gc.freeze()
        rt.queue.start()
        rt.watches.start_netapps(namespaces, lambda body, deleted: netapp_seen(rt, body, deleted))
        rt.task = asyncio.create_task(_periodic(rt), name="netapp-operator-checks")
        if rt.rollouts is not None:
            rt.rollout_task = asyncio.create_task(_poll_rollouts(rt, rt.rollouts), name="netapp-operator-rollouts")
        rt.idle = IdlePoller(kube, rt.cache, reconciler.event, config.rollout_timeout_seconds)
        rt.idle_task = asyncio.create_task(_poll_idle(rt, rt.idle), name="netapp-operator-idle")
        if config.waker_ip:
            rt.waker = Waker(kube, rt.cache, rt.changed)
            await rt.waker.open(config.waker_ip, config.waker_port)

    @kopf.on.cleanup(registry=registry)
    async def cleanup(**_: Any) -> None:
        gc.unfreeze()
        await cancel([t for t in (rt.task, rt.rollout_task, rt.idle_task) if t is not None])
        for part in (rt.watches, rt.queue):
            if part is not None:
                await part.stop()
        for poller in (rt.rollouts, rt.idle, rt.waker):
            if poller is not None:
                await poller.close()
        if rt.reconciler is not None:
            await rt.reconciler.kube.close()
        if rt.metrics is not None:
            await rt.metrics.cleanup()

    # --- what the cache watches --------------------------------------------------------------------------
    # Coroutines although they do no I/O: kopf runs a plain function in a worker thread, a thread hop per event.

    @kopf.on.event("v1", "nodes", registry=registry)
    async def node_event(event: dict[str, Any], **_: Any) -> None:
        rt.cache.on_node(event["object"], deleted=event.get("type") == "DELETED")

    @kopf.on.event(**nodepools, registry=registry)
    async def nodepool_event(event: dict[str, Any], **_: Any) -> None:
        rt.cache.on_nodepool(event["object"], deleted=event.get("type") == "DELETED")
        if rt.prepull is not None:
            try:
                await rt.prepull.sync(event["object"], deleted=event.get("type") == "DELETED")
            except ApiError as exc:  # the pool's netapps do not depend on it: say so, retried at its next event
                logger.warning("NodePool %s: its pre-pull DaemonSet: %s", event["object"]["metadata"]["name"], exc)

    return rt


def netapp_seen(rt: Runtime, body: dict[str, Any], deleted: bool) -> None:
    """A NetApp's watch event (or a listing's item): into the cache, and queued unless deleted (its children go
    with it through their owner references)."""
    rt.cache.on_netapp(body, deleted=deleted)
    meta = body["metadata"]
    key = (meta.get("namespace"), meta["name"])
    if deleted:
        if rt.reconciler is not None:
            rt.reconciler.leftovers.pop(key, None)
    else:
        rt.changed(key)


async def _prime(rt: Runtime, kube: Kube) -> None:
    """Fill the cache's nodes and pools before any NetApp is reconciled: otherwise a restarted operator would see
    no pools and mark every NetApp Pending."""
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


async def _periodic(rt: Runtime) -> None:
    assert rt.reconciler is not None
    while True:
        await asyncio.sleep(rt.config.check_interval_seconds)
        try:
            await rt.reconciler.check_all(rt.changed)
        except Exception:
            logger.exception("periodic placement check failed")
        rt.checks += 1


async def _poll_rollouts(rt: Runtime, poller: RolloutPoller) -> None:
    """The NetApps trying a new model, from the cache: each one's pod is asked how it goes, every
    `rollout_poll_seconds` (docs/rollouts.md#kubernetes). A loop of its own rather than a kopf timer, which would put
    a finalizer on each such NetApp (and a patch to add it and one to remove it); nor in the work queue, where a slow
    netapp would hold a reconcile worker. Each tick is bounded by its requests' timeouts and never raises."""
    while True:
        await asyncio.sleep(rt.config.rollout_poll_seconds)
        trying = [netapp for netapp in list(rt.cache.netapps.values()) if poller.active(netapp)]
        poller.forget_others(trying)
        try:
            await asyncio.gather(*(poller.tick(netapp) for netapp in trying))
        except Exception:
            logger.exception("polling the model rollouts failed")


async def _poll_idle(rt: Runtime, poller: IdlePoller) -> None:
    """The NetApps that may sleep (spec.scaling.idleToZero), from the cache: each one's pods are asked for their
    robots every `idle_poll_seconds` (netapp_operator.idle_poll); a loop of its own, like the rollouts'."""
    while True:
        await asyncio.sleep(rt.config.idle_poll_seconds)
        try:
            await asyncio.gather(*(poller.tick(netapp) for netapp in poller.watched()))
        except Exception:
            logger.exception("the idle check failed")
