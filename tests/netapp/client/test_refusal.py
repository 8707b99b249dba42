"""A refusal reaches robot code as what it is, at once: `NetAppRefused` with its reason, limit and Retry-After,
over every transport; the next URL serves; one URL is tried again after Retry-After within the connect budget;
`netapp stream` prints one line; INIT never waits behind inference."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest
import socketio

from netapp.client import NetAppClient, NetAppRefused
from netapp.client.errors import refusal
from netapp.client.link import NetAppLink
from netapp.client.pacing import Pacer
from netapp.client.wire import WireSequencer
from netapp.protocol import COMMAND_EVENT, CONTROL_NAMESPACE, DATA_NAMESPACE, IMAGE_EVENT, CommandType
from netapp.server.access import token_digest
from netapp.server.settings import Settings
from tests.support.images import make_jpeg

TRANSPORTS = ["http", "ws", "h264", "frames"]


@pytest.fixture
def full_server(serve, tiny_detector):
    """A netapp whose one session is taken."""
    server = serve(tiny_detector, Settings(lanes=1, max_sessions=1))
    holder = NetAppClient(server.url, transport="http").connect()
    yield server
    holder.close()


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_a_full_netapp_refuses_at_once_saying_why(full_server, transport):
    if transport == "h264":
        pytest.importorskip("av")
    started = time.monotonic()
    with pytest.raises(NetAppRefused) as refused:
        NetAppClient(full_server.url, transport=transport, connect_timeout_s=3).connect()
    took_s = time.monotonic() - started
    error = refused.value
    assert (error.reason, error.limit, error.retry_after_s) == ("sessions_full", 1, 5)
    assert str(error) == f"{full_server.url} refused: sessions full (limit 1, retry after 5 s)"
    assert "limit of 1 sessions" in error.detail  # the netapp's own words are kept
    assert took_s < 2.5, f"a refusal is an answer, not a timeout ({took_s:.1f} s)"  # Retry-After 5 > budget 3


@pytest.mark.parametrize("transport", ["http", "ws", "frames"])
def test_a_wrong_token_is_refused_as_a_bad_token(serve, tiny_detector, transport):
    server = serve(tiny_detector, Settings(lanes=1, token_sha256=token_digest("right")))
    with pytest.raises(NetAppRefused) as refused:
        NetAppClient(server.url, transport=transport, token="wrong", connect_timeout_s=3).connect()
    assert refused.value.reason == "unauthorized"
    assert str(refused.value).startswith(f"{server.url} refused: bad token: this netapp needs a token")
    with NetAppClient(server.url, transport=transport, token="right") as client:
        client.send(make_jpeg())
        assert next(iter(client.results(timeout=20))).detections


@pytest.mark.parametrize("transport", ["http", "ws", "frames"])
def test_with_several_urls_the_next_one_serves(full_server, serve, tiny_detector, transport):
    free = serve(tiny_detector)
    errors = []
    with NetAppClient([full_server.url, free.url], transport=transport, on_error=errors.append) as client:
        client.send(make_jpeg())
        result = next(iter(client.results(timeout=20)))
    assert result.source == free.url
    assert errors[0]["reason"] == "sessions_full" and "sessions full (limit 1" in errors[0]["error"]


def test_netapp_stream_prints_one_line(full_server, tmp_path):
    image = tmp_path / "frame.jpg"
    image.write_bytes(make_jpeg())
    command = [sys.executable, "-m", "netapp", "stream", full_server.url, "--source", str(image), "--duration", "1"]
    out = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert out.returncode == 1
    assert out.stderr.strip().splitlines() == [
        f"error: {full_server.url} refused: sessions full (limit 1, retry after 5 s)"
    ]


class _Refusing:
    """A transport that is refused `times` times with a Retry-After, then opens."""

    def __init__(self, times: int, retry_after_s: float, callbacks) -> None:
        self.times, self.retry_after_s, self.callbacks = times, retry_after_s, callbacks
        self.tries = 0
        self.session_id = None

    def connect(self) -> None:
        self.tries += 1
        if self.tries <= self.times:
            fields = {"reason": "sessions_full", "limit": 2, "retry_after_s": self.retry_after_s}
            raise refusal("http://n", fields)
        self.callbacks.on_ready()

    def close(self) -> None:
        pass


class _Events:
    def __getattr__(self, name):
        return lambda *args: None


def _link(transport: list) -> NetAppLink:
    def open_session(url, callbacks):
        transport[0].callbacks = callbacks
        return transport[0]

    return NetAppLink(0, "http://n", None, Pacer(1), open_session, _Events(), WireSequencer(), threading.Event())


def test_one_url_is_tried_again_after_retry_after_within_the_connect_budget():
    class Encoder:
        def restart(self):
            pass

    transport = [_Refusing(2, 0.05, None)]
    link = _link(transport)
    link.encoder = Encoder()
    link.open(retry_within_s=1.0)
    assert transport[0].tries == 3 and link.connected

    transport[0] = _Refusing(1, 5.0, None)  # Retry-After past the budget: the refusal, at once
    started = time.monotonic()
    with pytest.raises(NetAppRefused):
        link.open(retry_within_s=1.0)
    assert time.monotonic() - started < 0.5 and transport[0].tries == 1


def test_init_is_acknowledged_while_a_frame_holds_the_inference_lane(serve, gated):
    server = serve(gated)
    busy = socketio.Client()
    robot = socketio.Client()
    try:
        busy.connect(server.url, namespaces=[DATA_NAMESPACE, CONTROL_NAMESPACE], transports=["websocket"])
        init = {"cmd_type": int(CommandType.INIT), "data": {}}
        assert busy.call(COMMAND_EVENT, init, namespace=CONTROL_NAMESPACE, timeout=10)[0] is True
        busy.emit(IMAGE_EVENT, {"timestamp": 1, "frame": make_jpeg()}, namespace=DATA_NAMESPACE)
        assert gated.entered.acquire(timeout=10)  # the only lane is held by this frame
        robot.connect(server.url, namespaces=[DATA_NAMESPACE, CONTROL_NAMESPACE], transports=["websocket"])
        started = time.monotonic()
        ack = robot.call(COMMAND_EVENT, init, namespace=CONTROL_NAMESPACE, timeout=10)
        assert ack[0] is True and time.monotonic() - started < 1.0
        assert not gated.gate.is_set()  # acknowledged while inference was still held
    finally:
        gated.gate.set()
        robot.disconnect()
        busy.disconnect()


def test_processor_info_sends_the_token(monkeypatch):
    asked = {}

    class Answer:
        ok = True

        def json(self):
            return {"models": [{"name": "m"}]}

    def get(url, headers=None, timeout=None):
        asked.update(url=url, headers=headers)
        return Answer()

    monkeypatch.setattr("netapp.client.netapp_client.requests.get", get)
    client = NetAppClient("http://edge:5896", transport="http", token="s3cret")
    assert client.processor_info() == {"name": "m"}
    assert asked == {"url": "http://edge:5896/v2", "headers": {"Authorization": "Bearer s3cret"}}


@pytest.mark.parametrize("transport", ["http", "ws", "frames"])
def test_a_draining_netapp_is_a_refusal_saying_so(serve, tiny_detector, transport):
    server = serve(tiny_detector, Settings(lanes=1, drain_grace_s=30.0))
    server.call(server.app.drain()).result(timeout=10)  # no robots: drained at once, still answering
    with pytest.raises(NetAppRefused) as refused:
        NetAppClient(server.url, transport=transport, connect_timeout_s=0.5).connect()
    assert (refused.value.reason, refused.value.retry_after_s) == ("draining", 1)
    assert str(refused.value) == f"{server.url} refused: draining (retry after 1 s)"
