"""Optional netapp access control: with a token digest configured, every robot request needs the token."""

from __future__ import annotations

import pytest
import requests
import socketio

from netapp.protocol import CONTROL_NAMESPACE, DATA_NAMESPACE
from netapp.server.access import bearer, check_digest, socketio_token, token_digest
from netapp.server.settings import Settings
from tests.support.images import make_jpeg

TOKEN = "a-robot-token-of-the-netapp"


@pytest.fixture
def guarded(serve, tiny_detector):
    return serve(tiny_detector, Settings(token_sha256=token_digest(TOKEN))).url


def test_token_parsing() -> None:
    assert bearer("Bearer abc") == "abc" and bearer("bearer  abc ") == "abc"
    assert bearer("Basic abc") is None and bearer(None) is None and bearer("Bearer ") is None
    assert socketio_token({}, {"token": "a"}) == "a"
    assert socketio_token({"HTTP_AUTHORIZATION": "Bearer b"}, None) == "b"
    assert socketio_token({"QUERY_STRING": "EIO=4&token=c&transport=polling"}, None) == "c"
    assert socketio_token({}, None) is None
    assert check_digest(token_digest("x").upper()) == token_digest("x")
    with pytest.raises(ValueError, match="64 digits"):
        check_digest("abc")


def test_http_needs_the_token(guarded) -> None:
    url, good = guarded, {"Authorization": f"Bearer {TOKEN}"}
    for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": "Bearer t\u00e9".encode()}):
        refused = requests.post(f"{url}/register", json={}, headers=headers, timeout=5)
        assert refused.status_code == 401 and refused.json()["reason"] == "unauthorized"
        assert refused.headers["WWW-Authenticate"] == "Bearer"
    session = requests.post(f"{url}/register", json={}, headers=good, timeout=5).json()["session_id"]
    frame = {"X-Session-Id": session, "Content-Type": "image/jpeg"}
    assert requests.post(f"{url}/send_image", data=make_jpeg(), headers=frame, timeout=5).status_code == 401
    assert requests.get(f"{url}/results", headers={"X-Session-Id": session}, timeout=5).status_code == 401
    answered = requests.post(f"{url}/send_image?wait=true", data=make_jpeg(), headers={**frame, **good}, timeout=10)
    assert answered.status_code == 200 and answered.json()["detections"]
    assert requests.get(f"{url}/healthz", timeout=5).status_code == 200  # probes need no token
    assert 'reason="unauthorized"' in requests.get(f"{url}/metrics", timeout=5).text  # refused frames counted


@pytest.mark.parametrize("how", ["auth", "header", "query"])
def test_socketio_needs_the_token(guarded, how) -> None:
    refused, why = socketio.Client(reconnection=False), []
    refused.on("connect_error", why.append, namespace=DATA_NAMESPACE)
    with pytest.raises(socketio.exceptions.ConnectionError, match="failed to connect"):
        refused.connect(guarded, namespaces=[DATA_NAMESPACE, CONTROL_NAMESPACE], wait_timeout=10)
    assert "needs a token" in str(why)
    robot = socketio.Client(reconnection=False)
    options = {
        "auth": {"auth": {"token": TOKEN}},
        "header": {"headers": {"Authorization": f"Bearer {TOKEN}"}},
        "query": {},
    }[how]
    url = f"{guarded}?token={TOKEN}" if how == "query" else guarded
    robot.connect(url, namespaces=[DATA_NAMESPACE, CONTROL_NAMESPACE], wait_timeout=10, **options)
    try:
        ok, _ = robot.call("command", {"cmd_type": 1, "data": {}}, namespace=CONTROL_NAMESPACE, timeout=10)
        assert ok
    finally:
        robot.disconnect()
