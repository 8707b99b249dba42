"""NetAppClient: both transports, the in-flight bound (newest wins), callbacks, reconnection, switching URL."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import requests

from netapp.client import NetAppClient
from netapp.client.errors import MAX_ERROR_TEXT, response_error
from netapp.client.netapp_client import NetAppError
from netapp.server.app import create_app
from tests.support.client_internals import socketio_way
from tests.support.images import make_jpeg
from tests.support.onnx_models import TINY_NAMES
from tests.support.servers import BackgroundServer


@pytest.mark.parametrize("transport", ["http", "ws", "frames"])
def test_send_arrays_and_jpeg_bytes_get_results(tiny_server, transport):
    with NetAppClient(tiny_server.url, transport=transport) as client:
        t1 = client.send(np.full((96, 128, 3), 50, np.uint8))
        assert client.wait_idle(20)
        t2 = client.send(make_jpeg())
        assert client.wait_idle(20)
        results = list(client.results(timeout=0.5))
    assert [r.timestamp for r in results] == [t1, t2]
    assert all(r.detections[0]["class_name"] == TINY_NAMES[2] and r.latency_ms > 0 for r in results)


@pytest.mark.parametrize("transport", ["http", "ws", "frames"])
def test_never_more_than_max_in_flight_and_newest_wins(serve, gated, transport):
    server = serve(gated)
    with NetAppClient(server.url, transport=transport, max_in_flight=1) as client:
        first = client.send(make_jpeg())
        assert gated.entered.acquire(timeout=10)  # frame 1 reached the processor and is held there
        later = [client.send(make_jpeg()) for _ in range(5)]
        assert client.stats.sent == 1  # the bound holds: nothing else went on the wire
        assert client.stats.dropped_client == 4  # frames 2..5 superseded in the slot, 6 waits
        gated.gate.set()
        assert client.wait_idle(20)
        got = [r.timestamp for r in client.results(timeout=0.5)]
    assert got == [first, later[-1]]


@pytest.mark.parametrize("transport", ["http", "ws", "frames"])
def test_a_frame_the_netapp_supersedes_frees_its_slot_at_once(serve, gated, transport):
    """Newest wins in the netapp's queue too: the robot hears of it (409, or a `superseded` data_error) while the
    processor still holds the first frame, so the slot is free again and nothing waits out result_timeout_s."""
    server = serve(gated)
    with NetAppClient(server.url, transport=transport, max_in_flight=3, result_timeout_s=60) as client:
        first = client.send(make_jpeg())
        assert gated.entered.acquire(timeout=10)  # held in the processor
        client.send(make_jpeg())  # queued on the netapp
        client.send(make_jpeg())  # supersedes the queued one there (or, over HTTP, whichever arrived first)
        deadline = time.monotonic() + 10
        while client.stats.dropped_server < 1:
            assert time.monotonic() < deadline, client.stats
            time.sleep(0.02)  # polling with a deadline
        gated.gate.set()
        assert client.wait_idle(20)
        got = [r.timestamp for r in client.results(timeout=0.5)]
    assert len(got) == 2 and first in got and client.stats.dropped_server == 1
    assert client.stats.lost == 0 and client.stats.errors == 0


def test_callbacks_receive_results_and_errors(tiny_server):
    results, errors = [], []
    done = threading.Event()

    def on_result(r):
        results.append(r)
        done.set()

    with NetAppClient(tiny_server.url, transport="ws", on_result=on_result, on_error=errors.append) as client:
        client.send(b"\xff\xd8\xffnot really a jpeg")
        assert client.wait_idle(20)
        client.send(make_jpeg())
        assert done.wait(20)
    assert len(results) == 1 and "corrupt JPEG" in errors[0]["error"]
    assert client.stats.errors == 1


def test_http_errors_reach_on_error_with_the_netapps_message(tiny_server):
    errors, done = [], threading.Event()

    def on_error(message):
        errors.append(message)
        done.set()

    with NetAppClient(tiny_server.url, transport="http", on_error=on_error) as client:
        client.send(b"\xff\xd8\xffnot really a jpeg")
        assert done.wait(20)
    assert "corrupt JPEG" in errors[0]["error"] and 400 <= errors[0]["status"] < 500
    assert client.stats.errors == 1 and client.stats.last_error == errors[0]["error"]


def test_error_bodies_are_read_one_way():
    """`error_body` answers give their message; others (FastAPI's `detail`, plain text) their whole text."""

    def answer(status: int, body: bytes) -> requests.Response:
        response = requests.Response()
        response.status_code, response._content, response.encoding = status, body, "utf-8"
        return response

    assert response_error(answer(404, b'{"error": "unknown session", "reason": "unknown_session"}')) == (
        "unknown session"
    )
    assert response_error(answer(404, b'{"detail": "deployment not found"}')) == '{"detail": "deployment not found"}'
    assert response_error(answer(502, b"Bad Gateway")) == "Bad Gateway"
    assert len(response_error(answer(500, b"x" * 10_000_000))) == MAX_ERROR_TEXT  # a hostile body stays short


@pytest.mark.parametrize("transport", ["ws", "frames"])
def test_a_websocket_client_reconnects_after_the_server_restarts(tiny_detector, transport):
    first = BackgroundServer(create_app(tiny_detector)).start()
    port = int(first.url.rsplit(":", 1)[1])
    client = NetAppClient(first.url, transport=transport).connect()
    try:
        client.send(make_jpeg())
        assert client.wait_idle(20) and client.stats.results == 1
        first.stop()
        deadline = time.monotonic() + 20
        while client.connected:
            assert time.monotonic() < deadline
            time.sleep(0.02)
        second = BackgroundServer(create_app(tiny_detector), port=port).start()
        try:
            deadline = time.monotonic() + 30
            while not client.connected:  # reconnect and INIT again, by itself
                assert time.monotonic() < deadline, "the client did not reconnect"
                time.sleep(0.05)
            client.send(make_jpeg())
            assert client.wait_idle(20)
            assert client.stats.results == 2
        finally:
            second.stop()
    finally:
        client.close()


@pytest.mark.parametrize("transport", ["http", "ws", "frames"])
def test_switch_url_moves_to_another_netapp(serve, tiny_detector, transport):
    a, b = serve(tiny_detector), serve(tiny_detector)
    with NetAppClient(a.url, transport=transport) as client:
        client.send(make_jpeg())
        assert client.wait_idle(20)
        client.switch_url(b.url)
        client.send(make_jpeg())
        assert client.wait_idle(20)
        assert client.stats.results == 2 and client.url == b.url


def test_unreachable_netapp_is_a_clear_error():
    with pytest.raises(NetAppError, match="cannot"):
        NetAppClient("http://127.0.0.1:9", transport="http", connect_timeout_s=2).connect()
    with pytest.raises(NetAppError, match="cannot connect"):
        NetAppClient("http://127.0.0.1:9", transport="ws", connect_timeout_s=2).connect()
    with pytest.raises(NetAppError, match="cannot connect"):
        NetAppClient("http://127.0.0.1:9", transport="frames", connect_timeout_s=2).connect()
    with pytest.raises(ValueError, match="transport"):
        NetAppClient("http://x", transport="carrier-pigeon")


def test_client_imports_no_server_code():
    import subprocess
    import sys

    code = (
        "import sys, netapp.client, netapp.apps.streaming, netapp.apps.stream; "
        "bad = [m for m in sys.modules if m.startswith(('netapp.server', 'netapp.models', 'fastapi', "
        "'onnxruntime', 'uvicorn'))]; print(bad); sys.exit(1 if bad else 0)"
    )
    assert subprocess.run([sys.executable, "-c", code], capture_output=True).returncode == 0


def test_a_socketio_robot_goes_straight_to_websocket(tiny_server):
    with NetAppClient(tiny_server.url, transport="ws") as client:
        assert socketio_way(client) == "websocket"
        client.send(make_jpeg())
        assert client.wait_idle(20) and client.stats.results == 1


def test_a_socketio_robot_starts_with_long_polling_where_no_websocket_gets_through(tiny_detector):
    """A way that refuses WebSocket (here uvicorn without it; a proxy, in the field): the robot polls instead."""
    from netapp.server.runner import uvicorn_options
    from netapp.server.settings import Settings

    settings = Settings(lanes=1)
    app = create_app(tiny_detector, settings)
    with BackgroundServer(app, **uvicorn_options(settings), ws="none") as server:
        with NetAppClient(server.url, transport="ws") as client:
            assert socketio_way(client) == "polling"
            stamps = [client.send(make_jpeg()) for _ in range(3)]
            assert client.wait_idle(20)
            got = [r.timestamp for r in client.results(timeout=0.5)]
            closing = time.monotonic()
        # python-engineio's own close waits for the poll in flight, which the netapp ends only with its next ping
        assert time.monotonic() - closing < 5.0, "closing waited for the long-poll in flight (about 25 s)"
        deadline = time.monotonic() + 10
        while 'netapp_active_sessions{transport="ws"} 0.0' not in requests.get(f"{server.url}/metrics").text:
            assert time.monotonic() < deadline, "the netapp kept the session: the CLOSE never reached it"
            time.sleep(0.02)  # polling a metric with a deadline
    assert got and set(got) <= set(stamps) and stamps[-1] in got
    assert client.stats.errors == 0 and client.stats.lost == 0
