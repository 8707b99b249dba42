"""Thin async Kubernetes I/O: create-or-patch, delete, list, get, status patches, with the operator's credentials.

It speaks plain JSON over aiohttp (already under kopf), so every child is a dict from `render` and no client
models sit between the renderer and the API server. Credentials come from kopf's login (kubeconfig or the
in-cluster service account) and are refreshed the same way when the server answers 401.
"""

from __future__ import annotations

import asyncio
import base64
import json
import logging
import os
import ssl
import tempfile
from collections.abc import Awaitable, Callable, Mapping
from typing import Any

import aiohttp

from netapp_operator.constants import (
    API_VERSION,
    NETAPP_KIND,
    NETAPP_PLURAL,
    NODEPOOL_KIND,
    NODEPOOL_PLURAL,
    OPERATOR_MANAGER,
)

logger = logging.getLogger(__name__)

# kind -> (API prefix, plural); the only kinds the operator touches.
KINDS: dict[str, tuple[str, str]] = {
    "Deployment": ("/apis/apps/v1", "deployments"),
    "Service": ("/api/v1", "services"),
    "HorizontalPodAutoscaler": ("/apis/autoscaling/v2", "horizontalpodautoscalers"),
    NETAPP_KIND: (f"/apis/{API_VERSION}", NETAPP_PLURAL),
    NODEPOOL_KIND: (f"/apis/{API_VERSION}", NODEPOOL_PLURAL),
    "Node": ("/api/v1", "nodes"),
}
CHILD_KINDS = ("Deployment", "Service", "HorizontalPodAutoscaler")


class ApiError(Exception):
    """An API server answer other than 2xx."""

    def __init__(self, status: int, reason: str, body: Any = None) -> None:
        super().__init__(f"{status} {reason}")
        self.status = status
        self.reason = reason
        self.body = body


def path(kind: str, namespace: str | None = None, name: str | None = None, subresource: str | None = None) -> str:
    prefix, plural = KINDS[kind]
    out = prefix + (f"/namespaces/{namespace}" if namespace else "") + f"/{plural}"
    if name:
        out += f"/{name}"
    if subresource:
        out += f"/{subresource}"
    return out


def _ssl_context(info: Any) -> ssl.SSLContext | bool:
    if not str(info.server).startswith("https"):
        return False
    ctx = ssl.create_default_context()
    if info.ca_path:
        ctx.load_verify_locations(cafile=os.fsdecode(info.ca_path))
    elif info.ca_data:
        data = info.ca_data.decode() if isinstance(info.ca_data, bytes) else info.ca_data
        if "BEGIN CERTIFICATE" not in data:
            data = base64.b64decode(data).decode()
        ctx.load_verify_locations(cadata=data)
    if info.insecure:
        ctx.check_hostname = False
        ctx.verify_mode = ssl.CERT_NONE
    cert, key = info.certificate_path, info.private_key_path
    tmp: list[str] = []
    try:
        # ssl only loads client certificates from files; kubeconfigs often embed them.
        for data, is_cert in ((info.certificate_data, True), (info.private_key_data, False)):
            if data:
                raw = data if isinstance(data, bytes) else data.encode()
                if b"-----BEGIN" not in raw:
                    raw = base64.b64decode(raw)
                fd, name = tempfile.mkstemp(suffix=".pem")
                with os.fdopen(fd, "wb") as f:
                    f.write(raw)
                tmp.append(name)
                if is_cert:
                    cert = name
                else:
                    key = name
        if cert:
            ctx.load_cert_chain(os.fsdecode(cert), os.fsdecode(key) if key else None)
    finally:
        for name in tmp:
            os.unlink(name)
    return ctx


class Kube:
    """One aiohttp session to the API server; `login` returns fresh kopf ConnectionInfo when credentials expire."""

    def __init__(
        self, login: Callable[[], Awaitable[Any]], timeout: float = 30.0, user_agent: str = f"{OPERATOR_MANAGER}/0.1"
    ) -> None:
        self._login = login
        self._user_agent = user_agent
        self._timeout = aiohttp.ClientTimeout(total=timeout)
        self._session: aiohttp.ClientSession | None = None
        self._server = ""
        self._lock = asyncio.Lock()

    async def _connect(self, force: bool = False) -> aiohttp.ClientSession:
        async with self._lock:
            if self._session is not None and not force:
                return self._session
            if self._session is not None:
                await self._session.close()
            info = await self._login()
            headers = {"User-Agent": self._user_agent, "Accept": "application/json"}
            auth = None
            if info.token:
                headers["Authorization"] = f"{info.scheme or 'Bearer'} {info.token}"
            elif info.username and info.password:
                auth = aiohttp.BasicAuth(info.username, info.password)
            self._server = str(info.server).rstrip("/")
            connector = aiohttp.TCPConnector(ssl=_ssl_context(info), limit=32)
            self._session = aiohttp.ClientSession(
                headers=headers, auth=auth, connector=connector, timeout=self._timeout
            )
            return self._session

    async def close(self) -> None:
        if self._session is not None:
            await self._session.close()
            self._session = None

    async def request(
        self,
        method: str,
        url: str,
        body: Any = None,
        *,
        params: Mapping[str, str] | None = None,
        content_type: str = "application/json",
    ) -> Any:
        for attempt in (1, 2):
            session = await self._connect(force=attempt == 2)
            data = None if body is None else json.dumps(body)
            headers = {"Content-Type": content_type} if body is not None else {}
            async with session.request(method, self._server + url, data=data, params=params, headers=headers) as resp:
                text = await resp.text()
                if resp.status == 401 and attempt == 1:
                    continue  # expired token: log in again once
                payload: Any = None
                if text:
                    try:
                        payload = json.loads(text)
                    except ValueError:
                        payload = text
                if resp.status >= 400:
                    reason = payload.get("message") if isinstance(payload, dict) else str(payload)[:200]
                    raise ApiError(resp.status, reason or resp.reason or "", payload)
                return payload
        raise AssertionError("unreachable")

    # --- verbs --------------------------------------------------------------------------------------------

    async def get(self, kind: str, namespace: str | None, name: str) -> dict[str, Any] | None:
        try:
            return await self.request("GET", path(kind, namespace, name))
        except ApiError as e:
            if e.status == 404:
                return None
            raise

    async def list(
        self, kind: str, namespace: str | None = None, labels: Mapping[str, str] | None = None
    ) -> list[dict[str, Any]]:
        selector = ",".join(f"{k}={v}" for k, v in (labels or {}).items())
        result = await self.request(
            "GET", path(kind, namespace), params={"labelSelector": selector} if selector else None
        )
        items = (result or {}).get("items", []) or []
        # Filter again here: not every server (nor emulator) honours label selectors, and a wrong delete is costly.
        return [
            i
            for i in items
            if (namespace is None or i.get("metadata", {}).get("namespace") == namespace)
            and all((i.get("metadata", {}).get("labels") or {}).get(k) == v for k, v in (labels or {}).items())
        ]

    async def apply(self, manifest: Mapping[str, Any]) -> dict[str, Any]:
        """Create or update a child idempotently with server-side apply.

        Apply also removes fields a previous render set and this one does not (a dropped init container, a
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
                    params={"fieldManager": OPERATOR_MANAGER, "force": "true"},
                    content_type="application/apply-patch+yaml",
                )
            except ApiError as e:
                if e.status != 404:
                    raise
            try:
                return await self.request("POST", path(kind, ns), manifest, params={"fieldManager": OPERATOR_MANAGER})
            except ApiError as e:
                if e.status != 409:
                    raise
        raise ApiError(409, f"{kind} {ns}/{name} kept appearing and disappearing")

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

    async def patch_status(
        self, kind: str, namespace: str | None, name: str, status: Mapping[str, Any]
    ) -> dict[str, Any] | None:
        try:
            return await self.request(
                "PATCH",
                path(kind, namespace, name, "status"),
                {"status": dict(status)},
                content_type="application/merge-patch+json",
            )
        except ApiError as e:
            if e.status == 404:  # deleted meanwhile: nothing to report on
                return None
            raise
