"""The waker: a sleeping NetApp's Service answers `waking` instead of refusing the connection (Knative's activator,
minimal; docs/kubernetes.md#scale-to-zero).

While a NetApp with `spec.scaling.idleToZero` has no ready pod (asleep, woken and starting, or starting for the
first time), the operator gives its Service one more EndpointSlice: labelled `kubernetes.io/service-name`, so
kube-proxy sends the Service's port `http` there too, to the operator's own pod (`--waker-ip`, `--waker-port`). The
Service is not changed (its selector, ClusterIP, NodePort and the NetApp's URL stay); once a pod is ready the slice
is deleted and the Service's own EndpointSlices carry its traffic alone again.

The waker tells which NetApp a request is for by its Host header: the host and port of `status.url`, the Service's
DNS names with its port, its ClusterIP with its port, or its NodePort (unique in a cluster). It answers the netapp's
protocols' first request (HTTP, Socket.IO, the `frames` WebSocket: all begin as HTTP) as the local backend's sleeping
port does, 503 `waking` with `Retry-After: 0`, and wakes a sleeping NetApp by removing its `status.idle` (the sleep is
the operator's own: it needs no right to write the NetApp itself). A robot's client tries again every 50 to 200 ms
(netapp.client.link's WAKE_RETRY_S) until a pod answers. A Host it knows no NetApp by gets 404 (nothing to wait for).
A NetApp served over TLS is not fronted: the waker cannot answer for its certificate (its Service refuses, and a
robot asks the middleware to wake it: MiddlewareClient.wake).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Iterable, Mapping
from typing import Any
from urllib.parse import urlsplit

from netapp_operator import idle, render
from netapp_operator.cache import Cache, Key
from netapp_operator.config import OperatorConfig
from netapp_operator.constants import OPERATOR_MANAGER
from netapp_operator.kube import Kube
from netapp_operator.placement import Pool
from netapp_operator.spec import NetAppSpec
from netapp_operator.wake_listener import WakeListener, host_of, http_answer, waking_answer

logger = logging.getLogger(__name__)

SERVICE_NAME_LABEL = "kubernetes.io/service-name"  # what kube-proxy joins a Service's EndpointSlices by
SLICE_MANAGED_BY_LABEL = "endpointslice.kubernetes.io/managed-by"  # not the EndpointSlice controller's: ours
UNKNOWN_NETAPP_REASON = "unknown_netapp"
MAX_HOSTS = 4096  # Hosts remembered (a scan of the NetApps that may sleep each, else)
Address = tuple[str, int]  # (host, port)


def fronted(spec: NetAppSpec, deployment: Mapping[str, Any] | None) -> bool:
    """Whether the waker is an endpoint of the NetApp's Service: it may sleep, is not served over TLS, and has no
    ready pod."""
    if idle.idle_after_s(spec) is None or spec.tls is not None:
        return False
    return int(((deployment or {}).get("status") or {}).get("readyReplicas") or 0) == 0


def render_slice(netapp: Mapping[str, Any], pool: str, ip: str, port: int) -> dict[str, Any]:
    """The EndpointSlice that adds the waker (`ip`:`port`) to the Service of the NetApp on `pool` (its port `http`);
    named as the Service (the EndpointSlice controller's own are the Service's name and a suffix)."""
    meta = netapp["metadata"]
    name = render.child_name(meta["name"], pool)
    labels = {**render.labels(meta["name"], pool), SERVICE_NAME_LABEL: name, SLICE_MANAGED_BY_LABEL: OPERATOR_MANAGER}
    return {
        "apiVersion": "discovery.k8s.io/v1",
        "kind": "EndpointSlice",
        "metadata": {
            "name": name,
            "namespace": meta["namespace"],
            "labels": labels,
            "ownerReferences": [render.owner_reference(netapp)],
        },
        "addressType": "IPv6" if ":" in ip else "IPv4",
        "endpoints": [{"addresses": [ip], "conditions": {"ready": True, "serving": True, "terminating": False}}],
        "ports": [{"name": "http", "port": int(port), "protocol": "TCP"}],
    }


def split_host(host: str, default_port: int = 80) -> Address | None:
    """("name", port) of a Host header or a URL's netloc ("[::1]:80" too); None when unreadable."""
    try:
        parts = urlsplit(f"//{host}")
        return (parts.hostname or "", parts.port or default_port) if parts.hostname else None
    except ValueError:  # a port that is not a number, or out of range
        return None


def addresses(
    netapp: Mapping[str, Any], spec: NetAppSpec, service: Mapping[str, Any] | None
) -> tuple[set[Address], int | None]:
    """Where robots reach the NetApp: (host, port) pairs, and its NodePort (any host) or None."""
    meta, status = netapp["metadata"], netapp.get("status") or {}
    found: set[Address] = set()
    url = status.get("url")
    if url:
        parts = urlsplit(url)
        if parts.hostname:
            with contextlib.suppress(ValueError):
                found.add((parts.hostname.lower(), parts.port or (443 if parts.scheme == "https" else 80)))
    name, namespace, port = render.child_name(meta["name"], status.get("pool") or ""), meta["namespace"], spec.port
    for host in (name, f"{name}.{namespace}", f"{name}.{namespace}.svc", f"{name}.{namespace}.svc.cluster.local"):
        found.add((host, int(port)))
    service_spec = (service or {}).get("spec") or {}
    if service_spec.get("clusterIP") not in (None, "", "None"):
        found.add((str(service_spec["clusterIP"]), int(port)))
    node_port = next((p.get("nodePort") for p in service_spec.get("ports") or [] if p.get("name") == "http"), None)
    return found, int(node_port) if node_port else None


def netapp_at(host: str, candidates: Iterable[tuple[Key, set[Address], int | None]]) -> Key | None:
    """The NetApp a request with Host `host` is for: by its host and port first, else by a NodePort."""
    address = split_host(host)
    if address is None:
        return None
    by_node_port = None
    for key, known, node_port in candidates:
        if address in known:
            return key
        if node_port == address[1] and by_node_port is None:
            by_node_port = key
    return by_node_port


class Fronts:
    """The reconcile's part: which NetApps' Services have the waker's EndpointSlice (by uid and pool, as this operator
    gave them: a NetApp made again has another uid, one moved another Service), giving it while a NetApp has no ready
    pod and taking it away after (a moved NetApp's old one goes as its old Service does: stale children)."""

    def __init__(self, kube: Kube, cache: Cache, config: OperatorConfig) -> None:
        self.kube = kube
        self.cache = cache
        self.config = config
        self.given: dict[Key, tuple[str, str]] = {}  # NetApp -> (uid, pool)

    def wanted(self, netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool) -> bool:
        if not self.config.waker_ip:
            return False
        meta = netapp["metadata"]
        return fronted(
            spec, self.cache.deployments.get((meta["namespace"], render.child_name(meta["name"], pool.name)))
        )

    def given_to(self, netapp: Mapping[str, Any], pool: Pool) -> bool:
        meta = netapp["metadata"]
        return self.given.get((meta["namespace"], meta["name"])) == (meta.get("uid") or "", pool.name)

    def stale(self, netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool) -> bool:
        return self.wanted(netapp, spec, pool) != self.given_to(netapp, pool)

    async def sync(
        self, netapp: Mapping[str, Any], spec: NetAppSpec, pool: Pool, known: Iterable[tuple[str, str]] | None
    ) -> None:
        """Give or take the slice as `wanted` says; `known`: the children a restarted operator found."""
        meta = netapp["metadata"]
        key, name = (meta["namespace"], meta["name"]), render.child_name(meta["name"], pool.name)
        if self.wanted(netapp, spec, pool):
            if not self.given_to(netapp, pool):
                await self.kube.apply(render_slice(netapp, pool.name, self.config.waker_ip, self.config.waker_port))
                self.given[key] = (meta.get("uid") or "", pool.name)
        elif self.given_to(netapp, pool) or ("EndpointSlice", name) in set(known or ()):
            await self.kube.delete("EndpointSlice", meta["namespace"], name)
            self.given.pop(key, None)


class Waker:
    """The operator's listener for sleeping NetApps' Services (I/O over the functions above)."""

    def __init__(self, kube: Kube, cache: Cache, changed: Callable[[Key], None]) -> None:
        self.kube = kube
        self.cache = cache
        self.changed = changed  # queues a reconcile of the NetApp (its replicas back)
        self.listener = WakeListener(self.answer)
        self.waking = 0  # requests answered `waking`
        self.unknown = 0  # requests whose Host names no NetApp that may sleep
        self._waking: set[Key] = set()
        self._hosts: dict[str, Key] = {}  # Host -> NetApp, as matched (a robot's retries cost no scan)
        self._tasks: set[asyncio.Task[None]] = set()

    async def open(self, ip: str, port: int) -> None:
        await self.listener.open(ip, port)
        logger.info("waker: listening on %s:%d for sleeping NetApps' Services", ip, port)

    async def close(self) -> None:
        await self.listener.close()
        for task in list(self._tasks):
            task.cancel()

    def candidates(self) -> Iterable[tuple[Key, set[Address], int | None]]:
        """Each placed NetApp that may sleep, with where robots reach it."""
        for key, netapp in list(self.cache.netapps.items()):
            spec = self.cache.specs.get(key)
            pool = (netapp.get("status") or {}).get("pool")
            if spec is None or not pool or idle.idle_after_s(spec) is None:
                continue
            service = self.cache.services.get((key[0], render.child_name(key[1], pool)))
            yield (key, *addresses(netapp, spec, service))

    def answer(self, head: bytes) -> bytes:
        """Called for each request (on the loop): wakes the NetApp it is for, if it sleeps; the bytes to answer."""
        host = host_of(head)
        key = self._hosts.get(host)
        if key is None or key not in self.cache.netapps:
            key = netapp_at(host, self.candidates()) if host else None
            if key is not None:
                if len(self._hosts) >= MAX_HOSTS:
                    self._hosts.clear()
                self._hosts[host] = key
        if key is None:
            self.unknown += 1
            message = f"no NetApp that sleeps is known at {host or 'this address'}: ask the middleware for its URL"
            return http_answer("404 Not Found", message, UNKNOWN_NETAPP_REASON)
        netapp = self.cache.netapps.get(key)
        if netapp is not None and idle.asleep(netapp) and key not in self._waking:
            self._waking.add(key)
            task = asyncio.get_running_loop().create_task(self._wake(key))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)
        self.waking += 1
        return waking_answer()

    async def _wake(self, key: Key) -> None:
        try:
            written = await self.kube.patch_status("NetApp", key[0], key[1], idle.woken_status())
            if isinstance(written, dict) and written.get("metadata"):
                self.cache.on_netapp(written, deleted=False)  # the next request sees it awake: no second wake
            logger.info("NetApp %s/%s: a robot's request woke it", key[0], key[1])
            self.changed(key)
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # the API server: the robot's next request tries again
            logger.warning("waking NetApp %s/%s failed: %s", key[0], key[1], exc)
        finally:
            self._waking.discard(key)
