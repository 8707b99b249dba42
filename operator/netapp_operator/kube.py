"""The one Kubernetes client of the operator and the middleware: kubernetes_asyncio, spoken in plain dicts.

kubernetes_asyncio logs in (kubeconfig with exec plugins and embedded certificates, or the in-cluster service
account) and owns TLS, the auth settings and the aiohttp session; this module sends each request on that session
itself (`Kube._call`: the library's own per-request path cost more than the request) and adds what both callers need
on top: one error type (`ApiError`, with the server's message), one way to apply (server-side apply with a field
manager), one way to watch (list, then watch from the listing's resourceVersion, list again on 410 Gone), and
paths by kind, so every object stays the dict `render` made and no client model sits in between.
Nothing here imports kopf: the middleware uses it without the operator's extra.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import logging
import os
import urllib.parse
import urllib.request
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping
from typing import Any

import aiohttp
import orjson
from kubernetes_asyncio import client, config

from netapp_operator.constants import API_VERSION, NETAPP_KIND, NETAPP_PLURAL, NODEPOOL_KIND, NODEPOOL_PLURAL

logger = logging.getLogger(__name__)

# kind -> (API prefix, plural); the only kinds the operator and the middleware touch.
KINDS: dict[str, tuple[str, str]] = {
    "Deployment": ("/apis/apps/v1", "deployments"),
    "DaemonSet": ("/apis/apps/v1", "daemonsets"),  # a NodePool's image pre-pull (netapp_operator/prepull.py)
    "Service": ("/api/v1", "services"),
    "EndpointSlice": ("/apis/discovery.k8s.io/v1", "endpointslices"),  # a sleeping NetApp's waker (waker.py)
    "HorizontalPodAutoscaler": ("/apis/autoscaling/v2", "horizontalpodautoscalers"),
    "NetworkPolicy": ("/apis/networking.k8s.io/v1", "networkpolicies"),
    "ScaledObject": ("/apis/keda.sh/v1alpha1", "scaledobjects"),  # KEDA's, where KEDA is installed
    NETAPP_KIND: (f"/apis/{API_VERSION}", NETAPP_PLURAL),
    NODEPOOL_KIND: (f"/apis/{API_VERSION}", NODEPOOL_PLURAL),
    "Node": ("/api/v1", "nodes"),
    "Pod": ("/api/v1", "pods"),  # the pod a model rollout runs on (netapp_operator.rollout_poll)
    "Event": ("/api/v1", "events"),
    "Secret": ("/api/v1", "secrets"),
    "ConfigMap": ("/api/v1", "configmaps"),
    "Namespace": ("/api/v1", "namespaces"),
    "Lease": ("/apis/coordination.k8s.io/v1", "leases"),  # a netapp's cameras (netapp/server/sources/leases.py)
    # what a NetApp's replicas need for those Leases (netapp_operator/cameras.py)
    "ServiceAccount": ("/api/v1", "serviceaccounts"),
    "Role": ("/apis/rbac.authorization.k8s.io/v1", "roles"),
    "RoleBinding": ("/apis/rbac.authorization.k8s.io/v1", "rolebindings"),
}
CHILD_KINDS = ("Deployment", "Service", "NetworkPolicy", "HorizontalPodAutoscaler", "ScaledObject", "EndpointSlice")

Login = Callable[[], Awaitable[client.Configuration]]


class ApiError(Exception):
    """An API server answer other than 2xx; `reason` is the server's message (a Status' `message`)."""

    def __init__(self, status: int, reason: str, body: Any = None) -> None:
        super().__init__(f"{status} {reason}")
        self.status = status
        self.reason = reason
        self.body = body

    @classmethod
    def from_response(cls, status: int, reason: str | None, body: bytes | str | None) -> ApiError:
        """From an answer's status, reason phrase and body (a Status object, as the server sends it, or text)."""
        if isinstance(body, bytes):
            body = body.decode(errors="replace")
        parsed: Any = body
        with contextlib.suppress(TypeError, ValueError):
            parsed = json.loads(body) if body else None
        message = parsed.get("message") if isinstance(parsed, dict) else (str(parsed)[:200] if parsed else "")
        return cls(int(status or 0), message or reason or "", parsed)


def path(kind: str, namespace: str | None = None, name: str | None = None, subresource: str | None = None) -> str:
    prefix, plural = KINDS[kind]
    out = prefix + (f"/namespaces/{namespace}" if namespace else "") + f"/{plural}"
    if name:
        out += f"/{name}"
    if subresource:
        out += f"/{subresource}"
    return out


# --- logging in --------------------------------------------------------------------------------------------------


async def environment_login(kubeconfig: str | None = None) -> client.Configuration:
    """The in-cluster service account inside a pod (unless a kubeconfig is named), else the kubeconfig
    (`kubeconfig`, $KUBECONFIG or ~/.kube/config, exec plugins included)."""
    cfg = client.Configuration()
    if kubeconfig is None and os.environ.get("KUBERNETES_SERVICE_HOST"):
        config.load_incluster_config(client_configuration=cfg)
    else:
        await config.load_kube_config(config_file=kubeconfig, client_configuration=cfg, persist_config=False)
    return cfg


def _b64(data: str | bytes) -> str:
    """Kubeconfig *-data fields are base64 of PEM; kopf may hold either form."""
    raw = data if isinstance(data, bytes) else data.encode()
    return (base64.b64encode(raw) if b"-----BEGIN" in raw else raw).decode()


async def login_from_info(info: Any) -> client.Configuration:
    """A kopf ConnectionInfo (what kopf's own login produced, or a test's) as a kubernetes_asyncio configuration,
    through the library's kubeconfig loader so that embedded certificates are handled the one way it has."""
    cluster: dict[str, Any] = {"server": str(info.server)}
    if info.ca_path:
        cluster["certificate-authority"] = os.fsdecode(info.ca_path)
    elif info.ca_data:
        cluster["certificate-authority-data"] = _b64(info.ca_data)
    if info.insecure:
        cluster["insecure-skip-tls-verify"] = True
    user: dict[str, Any] = {}
    if info.token:
        user["token"] = info.token
    elif info.username and info.password:
        user.update(username=info.username, password=info.password)
    if info.certificate_path:
        user["client-certificate"] = os.fsdecode(info.certificate_path)
    elif info.certificate_data:
        user["client-certificate-data"] = _b64(info.certificate_data)
    if info.private_key_path:
        user["client-key"] = os.fsdecode(info.private_key_path)
    elif info.private_key_data:
        user["client-key-data"] = _b64(info.private_key_data)
    kubeconfig = {
        "apiVersion": "v1",
        "kind": "Config",
        "clusters": [{"name": "c", "cluster": cluster}],
        "users": [{"name": "u", "user": user}],
        "contexts": [{"name": "x", "context": {"cluster": "c", "user": "u"}}],
        "current-context": "x",
    }
    cfg = client.Configuration()
    await config.load_kube_config_from_dict(kubeconfig, client_configuration=cfg)
    return cfg


def _look_up_proxy_once(api: client.ApiClient, cfg: client.Configuration) -> None:
    """Read the proxy environment once, at login, instead of on every request.

    kubernetes_asyncio makes its aiohttp session with `trust_env=True`, and aiohttp then reads ~/.netrc and the
    proxy variables in a worker thread for each request: two thread hops that cost more than the request itself
    to an API server nearby (bench/operator_bench.py). The proxy a request to the API server would take is the
    same every time, so it is looked up here, given to the client explicitly, and the per-request lookup is
    turned off. The API server takes a bearer token or a client certificate, never netrc credentials.
    RELIES_ON aiohttp's `ClientSession._trust_env` (tests/operator/test_operator_kube.py checks it exists)."""
    rest = api.rest_client
    if not cfg.proxy:
        rest.proxy = env_proxy_for(cfg.host)
    rest.pool_manager._trust_env = False


def env_proxy_for(url: str) -> str | None:
    """The proxy that the environment (HTTPS_PROXY, NO_PROXY, ...) names for `url`, or None."""
    parts = urllib.parse.urlsplit(url)
    proxies = urllib.request.getproxies()
    if parts.scheme not in proxies or urllib.request.proxy_bypass_environment(parts.hostname or "", proxies):
        return None
    return proxies[parts.scheme]


def _selector(labels: Mapping[str, str] | None) -> str:
    return ",".join(f"{k}={v}" for k, v in (labels or {}).items())


def _labelled(obj: Mapping[str, Any], labels: Mapping[str, str] | None) -> bool:
    have = (obj.get("metadata") or {}).get("labels") or {}
    return all(have.get(k) == v for k, v in (labels or {}).items())


# --- the client --------------------------------------------------------------------------------------------------


class Kube:
    """One kubernetes_asyncio ApiClient, made on first use; `login` gives a fresh configuration when the server
    answers 401 (an expired token), and the request is tried once more. `manager` says who writes: the field
    manager of every create and apply, and the User-Agent."""

    def __init__(self, login: Login, *, manager: str, timeout: float = 30.0) -> None:
        self._login = login
        self.manager = manager
        self._timeout = aiohttp.ClientTimeout(total=timeout)
        self._api: client.ApiClient | None = None
        self._lock = asyncio.Lock()

    async def _client(self, fresh: bool = False) -> client.ApiClient:
        async with self._lock:
            if self._api is not None and not fresh:
                return self._api
            if self._api is not None:
                await self._api.close()
            cfg = await self._login()
            self._api = client.ApiClient(cfg)
            self._api.user_agent = self.manager
            _look_up_proxy_once(self._api, cfg)
            return self._api

    async def close(self) -> None:
        if self._api is not None:
            await self._api.close()
            self._api = None

    async def _call(
        self,
        method: str,
        url: str,
        body: Any,
        params: Mapping[str, str] | None,
        content_type: str,
        stream: bool = False,
        timeout: aiohttp.ClientTimeout | None = None,
    ) -> Any:
        """One request on the client's session and login, retried once with a fresh login on 401: the parsed JSON
        answer, or with `stream` the open response (whatever its status; the caller closes it).

        Not through kubernetes_asyncio's `call_api`, which spends more per request than the request costs an API
        server nearby (bench/operator_bench.py, py-spy: 37 % of the operator's CPU in a burst of 4,000): it copies
        and sanitizes headers, parameters and the body (every dict in a manifest), encodes with `json` into a str
        that aiohttp encodes again, and parses the answer through its model deserializer. Its login, TLS, proxy,
        session and auth settings (a refreshed token included) are the ones used here."""
        for attempt in (1, 2):
            api = await self._client(fresh=attempt == 2)
            rest = api.rest_client
            headers = {"Accept": "application/json", "Content-Type": content_type, **api.default_headers}
            query = list(params.items()) if params else []
            await api.update_params_for_auth(headers, query, ["BearerToken"])
            extra: dict[str, Any] = {}
            if rest.proxy:
                extra.update(proxy=rest.proxy, proxy_headers=rest.proxy_headers)
            if rest.server_hostname:
                extra["server_hostname"] = rest.server_hostname
            response = await rest.pool_manager.request(
                method,
                api.configuration.host + url + ("?" + urllib.parse.urlencode(query) if query else ""),
                headers=headers,
                data=None if body is None or method == "GET" else orjson.dumps(body),
                timeout=timeout or self._timeout,
                **extra,
            )
            if stream:
                return response
            async with response:
                data = await response.read()
            if response.status == 401 and attempt == 1:
                continue  # expired credentials: log in again once
            if not 200 <= response.status <= 299:
                raise ApiError.from_response(response.status, response.reason, data)
            try:
                return orjson.loads(data) if data else None
            except orjson.JSONDecodeError:
                return data.decode(errors="replace")  # as kubernetes_asyncio answered a body that is not JSON
        raise AssertionError("unreachable")

    async def request(
        self,
        method: str,
        url: str,
        body: Any = None,
        *,
        params: Mapping[str, str] | None = None,
        content_type: str = "application/json",
    ) -> Any:
        """Any API call, JSON in and out; raises ApiError."""
        return await self._call(method, url, body, params, content_type)

    # --- verbs --------------------------------------------------------------------------------------------

    async def get(self, kind: str, namespace: str | None, name: str) -> dict[str, Any] | None:
        try:
            return await self.request("GET", path(kind, namespace, name))
        except ApiError as e:
            if e.status == 404:
                return None
            raise

    async def list_with_version(
        self, kind: str, namespace: str | None = None, labels: Mapping[str, str] | None = None
    ) -> tuple[list[dict[str, Any]], str | None]:
        """The items and the listing's resourceVersion (where a watch starts)."""
        selector = _selector(labels)
        result = await self.request(
            "GET", path(kind, namespace), params={"labelSelector": selector} if selector else None
        )
        items = (result or {}).get("items", []) or []
        # Filter again here: not every server (nor emulator) honours label selectors, and a wrong delete is costly.
        kept = [
            i
            for i in items
            if (namespace is None or i.get("metadata", {}).get("namespace") in (namespace, None))
            and _labelled(i, labels)
        ]
        return kept, ((result or {}).get("metadata") or {}).get("resourceVersion")

    async def list(
        self, kind: str, namespace: str | None = None, labels: Mapping[str, str] | None = None
    ) -> list[dict[str, Any]]:
        return (await self.list_with_version(kind, namespace, labels))[0]

    async def create(self, manifest: Mapping[str, Any]) -> dict[str, Any]:
        meta = manifest["metadata"]
        return await self.request(
            "POST", path(manifest["kind"], meta.get("namespace")), manifest, params={"fieldManager": self.manager}
        )

    async def apply(self, manifest: Mapping[str, Any]) -> dict[str, Any]:
        """Create or update an object idempotently with server-side apply, owning its fields as our manager.

        Apply also removes fields a previous apply set and this one does not (a dropped init container, a
        pool's old tolerations), which a merge patch would keep, and it leaves fields owned by others alone
        (the HPA's replica count). A server that answers 404 to apply (some emulators) gets a create, and a
        409 on that create (someone was faster) goes back to apply: 404 and 409 are normal here."""
        meta = manifest["metadata"]
        kind, ns, name = manifest["kind"], meta.get("namespace"), meta["name"]
        for _ in range(3):
            try:
                return await self.request(
                    "PATCH",
                    path(kind, ns, name),
                    manifest,
                    params={"fieldManager": self.manager, "force": "true"},
                    content_type="application/apply-patch+yaml",
                )
            except ApiError as e:
                if e.status != 404:
                    raise
            try:
                return await self.create(manifest)
            except ApiError as e:
                if e.status != 409:
                    raise
        raise ApiError(409, f"{kind} {ns}/{name} kept appearing and disappearing")

    async def merge_patch(
        self, kind: str, namespace: str | None, name: str, patch: Mapping[str, Any], subresource: str | None = None
    ) -> dict[str, Any] | None:
        """A JSON merge patch (a status, one annotation); None when the object is gone."""
        try:
            return await self.request(
                "PATCH",
                path(kind, namespace, name, subresource),
                dict(patch),
                content_type="application/merge-patch+json",
            )
        except ApiError as e:
            if e.status == 404:  # deleted meanwhile: nothing to write on
                return None
            raise

    async def patch_status(
        self, kind: str, namespace: str | None, name: str, status: Mapping[str, Any]
    ) -> dict[str, Any] | None:
        return await self.merge_patch(kind, namespace, name, {"status": dict(status)}, "status")

    async def delete(self, kind: str, namespace: str | None, name: str) -> bool:
        """Delete in the background (dependents go with it); False when it was already gone."""
        try:
            await self.request(
                "DELETE",
                path(kind, namespace, name),
                {"kind": "DeleteOptions", "apiVersion": "v1", "propagationPolicy": "Background"},
            )
            return True
        except ApiError as e:
            if e.status == 404:
                return False
            raise

    async def watch(
        self,
        kind: str,
        namespace: str | None = None,
        *,
        labels: Mapping[str, str] | None = None,
        timeout_s: float = 60.0,
        retry_s: float = 0.5,
    ) -> AsyncIterator[tuple[str, Any]]:
        """List, then watch from the listing's resourceVersion, forever: yields ("LISTED", items) after every
        listing, then (event type, object) for each change, of the objects carrying `labels`. A watch the server
        ends (quiet for `timeout_s`), a 410 Gone (the version is too old) or a failure starts over with a new
        listing, which also reveals what was deleted while no watch was open."""
        failures = 0  # in a row: the first is a warning (e.g. a missing RBAC rule), the rest debug lines
        while True:
            try:
                items, version = await self.list_with_version(kind, namespace, labels)
                failures = 0
                yield "LISTED", items
                params = {"watch": "true", "timeoutSeconds": str(max(1, int(timeout_s * 0.8)))}
                if labels:
                    params["labelSelector"] = _selector(labels)
                if version:
                    params["resourceVersion"] = version
                # The server ends a quiet watch first; the client's read timeout is for a server that does not.
                response = await self._call(
                    "GET",
                    path(kind, namespace),
                    None,
                    params,
                    "application/json",
                    stream=True,
                    timeout=aiohttp.ClientTimeout(connect=5, sock_connect=5, sock_read=timeout_s),
                )
                async with response:
                    if response.status != 200:
                        raise ApiError(response.status, response.reason or "watch refused")
                    async for line in response.content:
                        if not line.strip():
                            continue
                        event = orjson.loads(line)
                        obj = event.get("object")
                        if event.get("type") == "ERROR" or not isinstance(obj, dict):
                            logger.debug("%s watch ends: %s", kind, obj)  # e.g. 410 Gone: list again
                            break
                        if _labelled(obj, labels):  # not every server (nor emulator) filters a watch
                            yield event["type"], obj
            except (ApiError, aiohttp.ClientError, ValueError, asyncio.TimeoutError) as e:
                # A quiet watch or the API server going away: list and watch again.
                failures += 1
                (logger.warning if failures == 1 else logger.debug)("%s watch restarts: %s", kind, e)
                await asyncio.sleep(retry_s)
