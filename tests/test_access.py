"""A netapp with a token: every robot entry point refuses a missing or wrong token (401 / `unauthorized`, or a
refused Socket.IO connect), a robot with the token streams on every transport, an unmodified 5G-ERA robot is
refused, and `netapp serve --token-file --tls-cert --tls-key` serves HTTPS and WSS with a certificate made here."""

from __future__ import annotations

import shutil
import subprocess
import sys

import numpy as np
import pytest
import requests
import socketio

from netapp.client import NetAppClient, NetAppError
from netapp.localproc import free_port, wait_http_ok
from netapp.server import access
from netapp.server.settings import Settings
from tests.conftest import TINY_NAMES, make_jpeg

TOKEN = "t0ken-" + "x" * 40
WRONG = {"none": None, "wrong": "not-the-token", "non-ascii": "tök€n", "empty": ""}


@pytest.fixture
def locked(serve, tiny_detector):
    return serve(tiny_detector, Settings(token=TOKEN))


def _auth(token: str | None) -> dict[str, str]:
    return {} if token is None else {"Authorization": f"Bearer {token}".encode()}  # bytes: any octet goes


def _assert_unauthorized(response: requests.Response) -> None:
    assert response.status_code == 401, response.text
    body = response.json()
    assert body["reason"] == "unauthorized" and "token" in body["error"]
    assert response.headers["WWW-Authenticate"] == "Bearer"


def test_bearer_and_check_are_strict_and_never_raise():
    assert access.bearer("Bearer abc") == "abc" and access.bearer("bearer  abc ") == "abc"
    assert access.bearer("Basic abc") is None and access.bearer(None) is None and access.bearer("Bearer") is None
    assert access.check(None, None) is None and access.check("", "anything") is None  # open netapp
    assert access.check("abc", "abc") is None
    assert access.check("abc", None) == access.MISSING
    for presented in ("abd", "ab", "abcd", "äbc", "\udcff"):
        assert access.check("abc", presented) == access.WRONG
    assert access.socketio_token({}, {"token": "a"}) == "a"
    assert access.socketio_token({"HTTP_AUTHORIZATION": "Bearer h"}, None) == "h"
    assert access.socketio_token({"HTTP_AUTHORIZATION": "Bearer h"}, {"token": 5}) == "h"


@pytest.mark.parametrize("case", WRONG)
def test_every_http_entry_point_refuses_without_the_token(locked, case):
    headers = _auth(WRONG[case])
    _assert_unauthorized(requests.post(f"{locked.url}/register", json={}, headers=headers, timeout=5))
    # A session registered with the token: its frames, results and unregister still need the token, every time.
    session = requests.post(f"{locked.url}/register", json={}, headers=_auth(TOKEN), timeout=5).json()["session_id"]
    frame = {"X-Session-Id": session, "Content-Type": "image/jpeg", **headers}
    _assert_unauthorized(requests.post(f"{locked.url}/send_image", data=make_jpeg(), headers=frame, timeout=5))
    _assert_unauthorized(requests.get(f"{locked.url}/results", headers={"X-Session-Id": session, **headers}, timeout=5))
    _assert_unauthorized(requests.post(f"{locked.url}/unregister", headers={"X-Session-Id": session, **headers}))
    # Probes and metrics stay open: the kubelet sends no token.
    assert requests.get(f"{locked.url}/readyz", timeout=5).ok
    metrics = requests.get(f"{locked.url}/metrics", timeout=5).text
    assert 'reason="unauthorized"' in metrics  # the refused frame is counted, with why


@pytest.mark.parametrize("how", ["none", "wrong-auth", "wrong-header"])
def test_socketio_connect_is_refused_without_the_token(locked, how):
    client = socketio.Client(reconnection=False)
    refusals = []
    for namespace in ("/data", "/control"):
        client.on("connect_error", lambda data, ns=namespace: refusals.append((ns, data)), namespace=namespace)
    kwargs = {"wrong-auth": {"auth": {"token": "nope"}}, "wrong-header": {"headers": {"Authorization": "Bearer no"}}}
    with pytest.raises(socketio.exceptions.ConnectionError):
        client.connect(locked.url, namespaces=["/data", "/control"], wait_timeout=5, **kwargs.get(how, {}))
    client.disconnect()
    assert sorted(ns for ns, _ in refusals) == ["/control", "/data"]
    for _, data in refusals:
        assert data["message"].startswith("unauthorized: ") and "token" in data["message"]


@pytest.mark.parametrize("how", ["auth", "header"])
def test_socketio_connect_with_the_token_in_auth_or_header(locked, how):
    client = socketio.Client(reconnection=False)
    kwargs = {"auth": {"auth": {"token": TOKEN}}, "header": {"headers": {"Authorization": f"Bearer {TOKEN}"}}}[how]
    client.connect(locked.url, namespaces=["/data", "/control"], wait_timeout=5, **kwargs)
    try:
        ok, _ = client.call("command", {"cmd_type": 1, "clear_queue": False, "data": {}}, namespace="/control")
        assert ok
    finally:
        client.disconnect()


@pytest.mark.parametrize("transport", ["http", "ws", "h264"])
def test_a_robot_with_the_token_streams_and_one_without_is_refused(locked, transport):
    if transport == "h264":
        pytest.importorskip("av", reason="PyAV is not installed")
    with NetAppClient(locked.url, transport=transport, token=TOKEN) as client:
        for _ in range(3):
            client.send(np.full((96, 128, 3), 50, np.uint8))
            assert client.wait_idle(20)
        results = list(client.results(timeout=0.5))
    assert len(results) == 3 and all(r.detections[0]["class_name"] == TINY_NAMES[2] for r in results)
    with pytest.raises(NetAppError, match="401|unauthorized"):
        NetAppClient(locked.url, transport=transport, token="wrong").connect()


def test_an_unmodified_5g_era_robot_is_refused_by_a_netapp_that_requires_a_token(locked):
    era = pytest.importorskip("era_5g_client.client_base", reason="era-5g-client is not installed (make install)")
    from era_5g_client.exceptions import FailedToConnect

    client = era.NetAppClientBase({})
    with pytest.raises(FailedToConnect):
        client.register(locked.url, args={"robot": "era"})


def test_an_open_netapp_takes_robots_without_a_token(tiny_server):
    assert requests.post(f"{tiny_server.url}/register", json={}, timeout=5).status_code == 201


# --- netapp serve: the token from a file, TLS -----------------------------------------------------------------------


@pytest.fixture
def certificate(tmp_path):
    """A self-signed certificate for 127.0.0.1, made with the openssl command line."""
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command is not installed (apt-get install openssl)")
    cert, key = tmp_path / "tls.crt", tmp_path / "tls.key"
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
        + ["-keyout", str(key), "-out", str(cert), "-days", "1", "-subj", "/CN=127.0.0.1"]
        + ["-addext", "subjectAltName=IP:127.0.0.1"],
        check=True,
        capture_output=True,
    )
    return cert, key


def test_netapp_serve_with_token_file_and_tls(tmp_path, tiny_model_path, certificate, monkeypatch):
    cert, key = certificate
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n")
    port = free_port()
    url = f"https://127.0.0.1:{port}"
    argv = [sys.executable, "-m", "netapp", "serve", "--model", str(tiny_model_path), "--port", str(port)]
    argv += ["--token-file", str(token_file), "--tls-cert", str(cert), "--tls-key", str(key)]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        monkeypatch.setenv("REQUESTS_CA_BUNDLE", str(cert))  # the robot trusts this certificate (and no other)
        wait_http_ok(f"{url}/readyz", proc, timeout_s=60)
        with pytest.raises(requests.exceptions.ConnectionError):
            requests.get(f"http://127.0.0.1:{port}/readyz", timeout=5)  # no plain HTTP beside HTTPS
        _assert_unauthorized(requests.post(f"{url}/register", json={}, timeout=5))
        with NetAppClient(url, transport="http", token=TOKEN) as client:
            client.send(make_jpeg())
            assert client.wait_idle(20)
            assert len(list(client.results(timeout=0.5))) == 1
        # WSS: python-engineio takes the CA from its HTTP session for the WebSocket too.
        http = requests.Session()
        http.verify = str(cert)
        sio = socketio.Client(reconnection=False, http_session=http)
        sio.connect(url, namespaces=["/data", "/control"], transports=["websocket"], auth={"token": TOKEN})
        try:
            ok, _ = sio.call("command", {"cmd_type": 1, "clear_queue": False, "data": {}}, namespace="/control")
            assert ok
        finally:
            sio.disconnect()
    finally:
        proc.terminate()
        proc.wait(10)


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--tls-cert", "c.pem"], "--tls-cert and --tls-key go together"),
        (["--token-file", "/nonexistent/token"], "cannot read --token-file"),
        (["--tls-cert", "/nonexistent/c.pem", "--tls-key", "/nonexistent/k.pem"], "cannot use --tls-cert"),
    ],
)
def test_netapp_serve_refuses_half_configured_access(tiny_model_path, extra, words):
    argv = [sys.executable, "-m", "netapp", "serve", "--model", str(tiny_model_path), *extra]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and words in done.stderr
