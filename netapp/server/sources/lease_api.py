"""The Kubernetes API as the camera Leases need it (get, create, merge-patch a Lease), over httpx, which the netapp
already has: a full Kubernetes client (kubernetes_asyncio and aiohttp) would add 71 MB to a 402 MB image whose goal is
425 MB (docs/decisions.md; measured with `pip install --target`).

Where it logs in (`lease_login`): a kubeconfig named by $KUBECONFIG (its current context: the server, its CA or
insecure-skip-tls-verify, a token or tokenFile), else the pod's service account (KUBERNETES_SERVICE_HOST, the token
file read again for every request, since the kubelet rotates bound tokens, and the cluster's CA), else none.
"""

from __future__ import annotations

import base64
import json
import os
import ssl
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

SERVICE_ACCOUNT_DIR = Path("/var/run/secrets/kubernetes.io/serviceaccount")
PREFIX = "/apis/coordination.k8s.io/v1"
TIMEOUT_S = 5.0  # a Lease round must end well within the Lease's own duration
MAX_ANSWER_BYTES = 1 << 20  # a Lease is well under 1 KiB; anything this large is not one
NO_LOGIN = "--camera-leases needs the Kubernetes API: run it in a pod (its service account), or set $KUBECONFIG"


class ApiError(Exception):
    """An answer other than 2xx; `status` is what leases.py reads (409: another replica won)."""

    def __init__(self, status: int, reason: str) -> None:
        super().__init__(f"{status} {reason}")
        self.status = status


@dataclass(frozen=True)
class Login:
    server: str
    verify: ssl.SSLContext | bool
    token: str | None = None
    token_file: Path | None = None

    def headers(self) -> dict[str, str]:
        token = self.token
        if self.token_file is not None:
            token = self.token_file.read_text().strip()
        return {"Authorization": f"Bearer {token}"} if token else {}


def lease_login(environ: Mapping[str, str] = os.environ) -> Login:
    """How this netapp reaches the API server; ValueError (one line) when it cannot."""
    if environ.get("KUBECONFIG"):
        return _from_kubeconfig(Path(environ["KUBECONFIG"].split(os.pathsep)[0]))
    host, port = environ.get("KUBERNETES_SERVICE_HOST"), environ.get("KUBERNETES_SERVICE_PORT", "443")
    if host:
        host = f"[{host}]" if ":" in host else host
        try:
            context = ssl.create_default_context(cafile=str(SERVICE_ACCOUNT_DIR / "ca.crt"))
        except (OSError, ssl.SSLError) as exc:
            raise ValueError(f"--camera-leases: the pod's service account is not mounted ({exc})") from None
        return Login(f"https://{host}:{port}", context, token_file=SERVICE_ACCOUNT_DIR / "token")
    raise ValueError(NO_LOGIN)


def _from_kubeconfig(path: Path) -> Login:
    import yaml  # here: only a netapp outside a pod, with --camera-leases, reads a kubeconfig

    try:
        config = yaml.safe_load(path.read_text())
        context = _named(config["contexts"], config["current-context"])["context"]
        cluster = _named(config["clusters"], context["cluster"])["cluster"]
        user = _named(config.get("users") or [], context.get("user"))["user"] if context.get("user") else {}
        server = str(cluster["server"])
    except (OSError, yaml.YAMLError, KeyError, TypeError) as exc:
        raise ValueError(f"--camera-leases: cannot read the kubeconfig {path} ({exc!r})") from None
    if user.get("exec") or user.get("client-certificate") or user.get("client-certificate-data"):
        raise ValueError(f"--camera-leases: the kubeconfig {path} needs a token user (no exec plugin, no client cert)")
    verify: ssl.SSLContext | bool = True
    if cluster.get("insecure-skip-tls-verify"):
        verify = False
    elif cluster.get("certificate-authority"):
        verify = ssl.create_default_context(cafile=cluster["certificate-authority"])
    elif cluster.get("certificate-authority-data"):
        pem = base64.b64decode(cluster["certificate-authority-data"]).decode()
        verify = ssl.create_default_context(cadata=pem)
    token_file = Path(user["tokenFile"]) if user.get("tokenFile") else None
    return Login(server.rstrip("/"), verify, token=user.get("token"), token_file=token_file)


def _named(items: Any, name: Any) -> dict[str, Any]:
    return next(i for i in items if i.get("name") == name)


class LeaseClient:
    """`leases.LeaseApi` over httpx: Leases only, bounded in time and size."""

    def __init__(self, login: Login) -> None:
        import httpx  # here: a netapp without cameras starts 50 ms sooner

        self.login = login
        self._client = httpx.AsyncClient(base_url=login.server, verify=login.verify, timeout=TIMEOUT_S)

    async def get(self, kind: str, namespace: str | None, name: str) -> dict[str, Any] | None:
        try:
            return await self._call("GET", _path(kind, namespace, name))
        except ApiError as exc:
            if exc.status == 404:
                return None
            raise

    async def create(self, manifest: Mapping[str, Any]) -> dict[str, Any]:
        meta = manifest["metadata"]
        return await self._call("POST", _path(manifest["kind"], meta["namespace"]), manifest)

    async def merge_patch(self, kind: str, namespace: str | None, name: str, patch: Mapping[str, Any]) -> Any:
        return await self._call("PATCH", _path(kind, namespace, name), patch, "application/merge-patch+json")

    async def _call(self, method: str, url: str, body: Any = None, content_type: str = "application/json") -> Any:
        headers = {**self.login.headers(), "Accept": "application/json"}
        if body is not None:
            headers["Content-Type"] = content_type
        async with self._client.stream(method, url, json=body, headers=headers) as answer:
            data = b""
            async for chunk in answer.aiter_bytes():
                data += chunk
                if len(data) > MAX_ANSWER_BYTES:
                    raise ApiError(answer.status_code, f"an answer over {MAX_ANSWER_BYTES} bytes")
        if answer.status_code >= 300:
            raise ApiError(answer.status_code, _reason(data))
        return json.loads(data) if data else None

    async def close(self) -> None:
        await self._client.aclose()


def _path(kind: str, namespace: str | None, name: str | None = None) -> str:
    if kind != "Lease" or not namespace:
        raise ValueError(f"only namespaced Leases here, not {kind}")
    return f"{PREFIX}/namespaces/{namespace}/leases" + (f"/{name}" if name else "")


def _reason(data: bytes) -> str:
    try:
        status = json.loads(data)
    except ValueError:
        status = None
    message = status.get("message") if isinstance(status, dict) else None
    return str(message or data[:200].decode(errors="replace"))[:300]
