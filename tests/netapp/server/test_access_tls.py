"""A netapp with a token, beyond test_access.py: `NetAppClient(token=...)` streams on every transport and a
robot without the token is told why, an unmodified 5G-ERA robot is refused, and `netapp serve --token-file
--tls-cert --tls-key` serves HTTPS and WSS only, with a self-signed certificate made here."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import numpy as np
import pytest
import requests
import socketio

from netapp.client import NetAppClient, NetAppError
from netapp.client.transports.engineio_compat import OneWayAtATimeWebSocket
from netapp.protocol import TOKEN_DIGEST_ENV, TOKEN_ENV
from netapp.serve_process import free_port, wait_http_ok
from netapp.server.access import token_digest
from netapp.server.settings import Settings
from tests.support.certificates import self_signed
from tests.support.client_internals import socketio_way
from tests.support.images import make_jpeg
from tests.support.onnx_models import TINY_NAMES

TOKEN = "t0ken-" + "x" * 40


@pytest.fixture
def locked(serve, tiny_detector):
    return serve(tiny_detector, Settings(token_sha256=token_digest(TOKEN)))


def _assert_unauthorized(response: requests.Response) -> None:
    assert response.status_code == 401, response.text
    assert response.json()["reason"] == "unauthorized" and "token" in response.json()["error"]


@pytest.mark.parametrize("transport", ["http", "ws", "h264", "frames"])
def test_a_robot_with_the_token_streams_and_one_without_is_refused(locked, transport):
    if transport == "h264":
        pytest.importorskip("av", reason="PyAV is not installed")
    with NetAppClient(locked.url, transport=transport, token=TOKEN) as client:
        for _ in range(3):
            client.send(np.full((96, 128, 3), 50, np.uint8))
            assert client.wait_idle(20)
        results = list(client.results(timeout=0.5))
    assert len(results) == 3 and all(r.detections[0]["class_name"] == TINY_NAMES[2] for r in results)
    with pytest.raises(NetAppError, match="needs a token"):  # the netapp's own words, not a bare status
        NetAppClient(locked.url, transport=transport, token="wrong").connect()


def test_an_unmodified_5g_era_robot_is_refused_by_a_netapp_that_requires_a_token(locked):
    era = pytest.importorskip("era_5g_client.client_base", reason="era-5g-client is not installed (make install)")
    from era_5g_client.exceptions import FailedToConnect

    client = era.NetAppClientBase({})
    with pytest.raises(FailedToConnect):
        client.register(locked.url, args={"robot": "era"})


def test_an_unmodified_5g_era_robot_presents_its_token_in_the_url(locked):
    """What docs/security.md#who-may-use-a-netapp-tokens-networkpolicies-tls tells an era-5g-client robot to do: it
    can only be given a URL."""
    era = pytest.importorskip("era_5g_client.client_base", reason="era-5g-client is not installed (make install)")
    client = era.NetAppClientBase({})
    client.register(f"{locked.url}?token={TOKEN}", args={"robot": "era"})
    try:
        assert client.initialized
    finally:
        threading.Thread(target=client.disconnect, daemon=True).start()  # as test_socketio.py: upstream's race


def test_an_open_netapp_takes_robots_without_a_token(tiny_server):
    assert requests.post(f"{tiny_server.url}/register", json={}, timeout=5).status_code == 201


# --- netapp serve: the token from a file, TLS -----------------------------------------------------------------------


@pytest.fixture
def certificate(tmp_path):
    """A self-signed certificate for 127.0.0.1."""
    return self_signed(tmp_path)


@pytest.mark.parametrize("given", ["file", "env"])
def test_netapp_serve_with_a_token_and_tls(tmp_path, tiny_model_path, certificate, monkeypatch, given):
    """The token from --token-file, or from NETAPP_TOKEN (how the operator passes a NetApp's token Secret)."""
    cert, key = certificate
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n")
    port = free_port()
    url = f"https://127.0.0.1:{port}"
    argv = [sys.executable, "-m", "netapp", "serve", "--model", str(tiny_model_path), "--port", str(port)]
    argv += ["--tls-cert", str(cert), "--tls-key", str(key)]
    env = {k: v for k, v in os.environ.items() if k not in (TOKEN_ENV, TOKEN_DIGEST_ENV)}
    if given == "file":
        argv += ["--token-file", str(token_file)]
    else:
        env[TOKEN_ENV] = TOKEN
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
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
        with NetAppClient(url, transport="ws", token=TOKEN) as client:  # WSS, trusting REQUESTS_CA_BUNDLE too
            assert socketio_way(client) == "websocket"
            client.send(make_jpeg())
            assert client.wait_idle(20) and client.stats.results == 1
        with NetAppClient(url, transport="frames", token=TOKEN) as client:  # WSS: REQUESTS_CA_BUNDLE trusted
            client.send(make_jpeg())
            assert client.wait_idle(20) and client.stats.results == 1
        # WSS from python-socketio itself: python-engineio takes the CA from its HTTP session for the WebSocket too.
        # Its threads race on the TLS socket (python-engineio #461: 1 to 5 connections in 100 lose a message), so
        # it reads and writes through NetAppClient's WebSocket class, as a 5G-ERA robot over TLS should.
        http = requests.Session()
        http.verify = str(cert)
        no_race = {"class_": OneWayAtATimeWebSocket}
        sio = socketio.Client(reconnection=False, http_session=http, websocket_extra_options=no_race)
        # wait_timeout: python-socketio's default of 1 s for the namespaces' answers is too short on a busy machine
        sio.connect(
            url, namespaces=["/data", "/control"], transports=["websocket"], auth={"token": TOKEN}, wait_timeout=10
        )
        try:
            command = {"cmd_type": 1, "clear_queue": False, "data": {}}
            ok, _ = sio.call("command", command, namespace="/control", timeout=10)
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
        (["--token-file", __file__, "--token-sha256", "0" * 64], "not both"),
    ],
)
def test_netapp_serve_refuses_half_configured_access(tiny_model_path, extra, words):
    argv = [sys.executable, "-m", "netapp", "serve", "--model", str(tiny_model_path), *extra]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and words in done.stderr
