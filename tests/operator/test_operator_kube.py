"""The API client against an HTTPS server like a real API server's: CA from kubeconfig data, bearer token,
a fresh login after a 401, create-or-apply with 404/409, and errors surfaced with the server's message."""

from __future__ import annotations

import base64
import json
import shutil
import ssl
import subprocess

import aiohttp.web
import kopf
import pytest
from netapp_operator.kube import ApiError, Kube, env_proxy_for, login_from_info

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")


@pytest.fixture(scope="module")
def certs(tmp_path_factory):
    d = tmp_path_factory.mktemp("pki")

    def sh(*args: str) -> None:
        subprocess.run(args, cwd=d, check=True, capture_output=True)

    sh(
        "openssl",
        "req",
        "-x509",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-keyout",
        "ca.key",
        "-out",
        "ca.crt",
        "-days",
        "1",
        "-subj",
        "/CN=test-ca",
    )
    sh(
        "openssl",
        "req",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-keyout",
        "srv.key",
        "-out",
        "srv.csr",
        "-subj",
        "/CN=127.0.0.1",
    )
    (d / "ext").write_text("subjectAltName=IP:127.0.0.1\n")
    sh(
        "openssl",
        "x509",
        "-req",
        "-in",
        "srv.csr",
        "-CA",
        "ca.crt",
        "-CAkey",
        "ca.key",
        "-CAcreateserial",
        "-out",
        "srv.crt",
        "-days",
        "1",
        "-extfile",
        "ext",
    )
    return d


async def test_tls_token_relogin_and_apply(certs):
    objects: dict[str, dict] = {}
    seen: list[tuple[str, str, str]] = []

    async def handler(request: aiohttp.web.Request) -> aiohttp.web.Response:
        seen.append((request.method, request.path, request.headers.get("Content-Type", "")))
        if request.headers.get("Authorization") != "Bearer fresh":
            return aiohttp.web.json_response({"kind": "Status", "message": "Unauthorized"}, status=401)
        if request.method == "PATCH":  # apply: this server, like kmock, answers 404 for a missing object
            if request.path not in objects:
                return aiohttp.web.json_response({"kind": "Status", "message": "not found"}, status=404)
            objects[request.path].update(json.loads(await request.text()))
            return aiohttp.web.json_response(objects[request.path])
        if request.method == "POST":
            body = json.loads(await request.text())
            path = f"{request.path}/{body['metadata']['name']}"
            if body["metadata"]["name"] == "bad":
                return aiohttp.web.json_response({"kind": "Status", "message": "spec.replicas: Invalid"}, status=422)
            objects[path] = body
            return aiohttp.web.json_response(body, status=201)
        return aiohttp.web.json_response(objects.get(request.path, {}))

    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    ctx.load_cert_chain(certs / "srv.crt", certs / "srv.key")
    app = aiohttp.web.Application()
    app.router.add_route("*", "/{tail:.*}", handler)
    runner = aiohttp.web.AppRunner(app)
    await runner.setup()
    site = aiohttp.web.TCPSite(runner, "127.0.0.1", 0, ssl_context=ctx)
    await site.start()
    port = site._server.sockets[0].getsockname()[1]
    ca_data = base64.b64encode((certs / "ca.crt").read_bytes()).decode()  # as in a kubeconfig
    tokens = iter(["stale", "fresh", "fresh"])
    logins = 0

    async def login():
        nonlocal logins
        logins += 1
        info = kopf.ConnectionInfo(server=f"https://127.0.0.1:{port}", ca_data=ca_data, token=next(tokens))
        return await login_from_info(info)

    kube = Kube(login, manager="netapp-operator-tests")
    try:
        svc = {
            "apiVersion": "v1",
            "kind": "Service",
            "metadata": {"name": "s", "namespace": "ns"},
            "spec": {"ports": [{"port": 80}]},
        }
        created = await kube.apply(svc)
        assert created["metadata"]["name"] == "s" and logins == 2  # the stale token cost one re-login
        again = await kube.apply({**svc, "spec": {"ports": [{"port": 81}]}})
        assert again["spec"]["ports"] == [{"port": 81}]
        apply_types = {ct for method, _, ct in seen if method == "PATCH"}
        assert apply_types == {"application/apply-patch+yaml"}
        with pytest.raises(ApiError) as err:
            await kube.apply({**svc, "metadata": {"name": "bad", "namespace": "ns"}})
        assert err.value.status == 422 and "spec.replicas" in err.value.reason
    finally:
        await kube.close()
        await runner.cleanup()


def test_env_proxy_for(monkeypatch):
    monkeypatch.setenv("HTTPS_PROXY", "http://proxy.example:3128")
    monkeypatch.setenv("NO_PROXY", "")
    assert env_proxy_for("https://10.0.0.1:6443") == "http://proxy.example:3128"
    assert env_proxy_for("http://10.0.0.1:8080") is None  # no HTTP_PROXY
    monkeypatch.setenv("NO_PROXY", "10.0.0.1,.cluster.local")
    assert env_proxy_for("https://10.0.0.1:6443") is None
    assert env_proxy_for("https://kubernetes.default.svc.cluster.local") is None


async def test_proxy_is_looked_up_once_at_login(monkeypatch):
    """The environment's proxy is given to the client at login, and aiohttp reads no environment per request.
    RELIES_ON aiohttp's ClientSession._trust_env (netapp_operator/kube.py): this fails if aiohttp renames it."""
    monkeypatch.setenv("HTTPS_PROXY", "http://proxy.example:3128")
    monkeypatch.setenv("NO_PROXY", "")

    async def login():
        return await login_from_info(kopf.ConnectionInfo(server="https://10.0.0.1:6443", token="t", insecure=True))

    kube = Kube(login, manager="netapp-operator-tests")
    try:
        api = await kube._client()
        assert api.rest_client.proxy == "http://proxy.example:3128"
        assert hasattr(api.rest_client.pool_manager, "_trust_env")
        assert api.rest_client.pool_manager._trust_env is False
    finally:
        await kube.close()


async def test_a_watch_selects_by_label_and_warns_once_while_refused(caplog):
    """The operator watches its own children by label; a server refusing the listing (a missing RBAC rule) is one
    warning, not one per retry, and not silence."""
    queries: list[dict[str, str]] = []

    def dep(name: str, labels: dict[str, str]) -> dict:
        return {"kind": "Deployment", "metadata": {"name": name, "namespace": "ns", "labels": labels}}

    ours, theirs = dep("ours", {"a": "b"}), dep("theirs", {})

    async def handler(request: aiohttp.web.Request) -> aiohttp.web.StreamResponse:
        queries.append(dict(request.query))
        if len(queries) <= 3:
            return aiohttp.web.json_response({"kind": "Status", "message": "forbidden"}, status=403)
        if request.query.get("watch") != "true":  # like kmock, this server ignores the selector
            return aiohttp.web.json_response({"metadata": {"resourceVersion": "5"}, "items": [ours, theirs]})
        response = aiohttp.web.StreamResponse()
        await response.prepare(request)
        for obj in (theirs, ours):
            await response.write(json.dumps({"type": "MODIFIED", "object": obj}).encode() + b"\n")
        return response

    app = aiohttp.web.Application()
    app.router.add_route("GET", "/{tail:.*}", handler)
    runner = aiohttp.web.AppRunner(app)
    await runner.setup()
    site = aiohttp.web.TCPSite(runner, "127.0.0.1", 0)
    await site.start()
    port = site._server.sockets[0].getsockname()[1]

    async def login():
        return await login_from_info(kopf.ConnectionInfo(server=f"http://127.0.0.1:{port}", token="t"))

    kube = Kube(login, manager="netapp-operator-tests")
    seen = []
    try:
        with caplog.at_level("DEBUG", logger="netapp_operator.kube"):
            async for kind, obj in kube.watch("Deployment", "ns", labels={"a": "b"}, retry_s=0.01):
                seen.append(
                    (kind, [o["metadata"]["name"] for o in obj] if kind == "LISTED" else obj["metadata"]["name"])
                )
                if kind != "LISTED":
                    break
    finally:
        await kube.close()
        await runner.cleanup()
    assert seen == [("LISTED", ["ours"]), ("MODIFIED", "ours")]
    assert queries[-1] == {"watch": "true", "timeoutSeconds": "48", "resourceVersion": "5", "labelSelector": "a=b"}
    warnings = [r for r in caplog.records if r.levelname == "WARNING" and "watch restarts" in r.getMessage()]
    assert len(warnings) == 1, caplog.text


async def test_requests_go_on_the_clients_session_without_its_per_request_path(api, monkeypatch):
    """Kube._call sends each request on kubernetes_asyncio's session and login itself: the library's `call_api`
    (sanitizing every body, its deserializer) was 37 % of the operator's CPU in a burst (bench/operator_bench.py).
    The answers and the errors read as before."""
    from kubernetes_asyncio import client

    def refuse(*_: object, **__: object) -> None:
        raise AssertionError("kubernetes_asyncio's call_api was used")

    monkeypatch.setattr(client.ApiClient, "call_api", refuse)
    secret = {"apiVersion": "v1", "kind": "Secret", "metadata": {"name": "s", "namespace": "ns"}, "data": {"a": "b"}}
    created = await api.create(secret)
    assert created["data"] == {"a": "b"} and created["metadata"]["uid"]
    assert (await api.get("Secret", "ns", "s"))["metadata"]["uid"] == created["metadata"]["uid"]
    assert await api.get("Secret", "ns", "missing") is None  # a 404
    with pytest.raises(ApiError) as refused:
        await api.create(secret)
    assert refused.value.status == 409
