"""Hostile input against a real `netapp serve` process, small versions of the attacks of issue 10 (the full-size
ones: bench/hostile.py), with a well-behaved robot streaming beside them all along.

Each attack must get its 4xx or error event; the server must stay up; the good robot's results must keep coming
(no gap over GAP_BOUND_S during an attack); the netapp's peak RSS must stay under RSS_BOUND.
"""

from __future__ import annotations

import json
import os
import platform
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import pytest
import requests

from netapp.protocol import CONTROL_NAMESPACE, DATA_NAMESPACE, H264_EVENT
from netapp.serve_process import free_port, wait_http_ok
from netapp.server.allocator import MMAP_THRESHOLD_BYTES, TRIM_THRESHOLD_BYTES
from netapp.server.http.head_deadline import MAX_HEAD_BYTES
from netapp.server.settings import Settings
from tests.netapp.server.test_socketio import RawRobot
from tests.support.attacks import h264_keyframe_claiming, jpeg_claiming
from tests.support.images import make_jpeg
from tests.support.raw_frames_robot import RawFramesRobot
from tests.support.watch import GoodRobot, rss_bytes

GAP_BOUND_S = 3.0  # longest the good robot may go without a result during an attack (2 shared cores in CI)
RSS_BOUND = 400 * 1024 * 1024  # the netapp's peak resident memory across every attack (measured: ~185 MiB)
MAX_SESSIONS, HEAD_TIMEOUT_S, BODY_TIMEOUT_S = 12, 1.0, 1.5


class Netapp:
    def __init__(self, process: subprocess.Popen, url: str, log: Path) -> None:
        self.process, self.url, self.log = process, url, log


@pytest.fixture(scope="module")
def netapp(tiny_model_path: Path, tmp_path_factory) -> Iterator[Netapp]:
    port = free_port()
    log = tmp_path_factory.mktemp("hostile") / "netapp.log"
    command = [sys.executable, "-m", "netapp", "serve", "--model", str(tiny_model_path), "--port", str(port)]
    command += ["--max-sessions", str(MAX_SESSIONS), "--prepare-threads", "0"]
    command += ["--head-timeout", str(HEAD_TIMEOUT_S), "--body-timeout", str(BODY_TIMEOUT_S)]
    with log.open("w") as out:
        process = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    try:
        wait_http_ok(f"{url}/readyz", process, timeout_s=60)
        yield Netapp(process, url, log)
    finally:
        process.terminate()
        process.wait(10)


@pytest.fixture(scope="module")
def good(netapp: Netapp) -> Iterator[GoodRobot]:
    with GoodRobot(netapp.url, own_process=True) as robot:  # as bench/hostile.py: not delayed by the attacker
        robot.wait_for_results(5)
        yield robot


@pytest.fixture
def attack(netapp: Netapp, good: GoodRobot):
    """Run the test's attack, then check the netapp is up and the good robot kept getting results meanwhile."""
    start = time.monotonic()
    yield netapp
    good.wait_for_results(len(good._results) + 3)  # results keep coming after the attack
    window = good.window(start)
    assert requests.get(f"{netapp.url}/healthz", timeout=5).status_code == 200
    assert window.longest_gap_s < GAP_BOUND_S, window
    assert window.failures == 0, window


def post_jpeg(url: str, session_id: str, data: bytes, **headers: str) -> requests.Response:
    return requests.post(
        f"{url}/send_image?wait=true",
        data=data,
        headers={"X-Session-Id": session_id, "Content-Type": "image/jpeg", **headers},
        timeout=10,
    )


def register(url: str) -> str:
    return requests.post(f"{url}/register", json={}, timeout=5).json()["session_id"]


def unregister(url: str, session_id: str) -> None:
    requests.post(f"{url}/unregister", headers={"X-Session-Id": session_id}, timeout=5)


def test_a_tiny_jpeg_claiming_a_huge_picture_is_refused_before_decoding(attack: Netapp) -> None:
    url = attack.url
    sessions = [register(url) for _ in range(4)]
    with ThreadPoolExecutor(4) as pool:  # from 4 sessions at once, as in the issue
        claims = [(65500, 16000), (60000, 60000), (30000, 30000), (30000, 30000)]
        replies = list(
            pool.map(lambda a: post_jpeg(url, a[0], jpeg_claiming(*a[1])), zip(sessions, claims, strict=True))
        )
    for reply in replies:
        assert reply.status_code == 413 and reply.json()["reason"] == "too_many_pixels", reply.text
    assert "65500x16000" in replies[0].json()["error"]
    robot = RawRobot(url)
    try:
        assert robot.init()[0]
        robot.frame({"timestamp": 7, "frame": jpeg_claiming(65500, 16000)})
        error = robot.next("data_error")
        assert (error["timestamp"], error["reason"]) == (7, "too_many_pixels")
    finally:
        robot.close()
    for session_id in sessions:
        unregister(url, session_id)


def test_an_h264_stream_whose_sps_claims_a_huge_picture_is_refused(attack: Netapp) -> None:
    pytest.importorskip("av")
    from netapp.client.h264 import H264Encoder

    packets, _ = H264Encoder(64, 64).encode(np.zeros((64, 64, 3), np.uint8))
    robot = RawRobot(attack.url)
    try:
        assert robot.init()[0]
        message = {"timestamp": 1, "frame": h264_keyframe_claiming(packets, 16000, 16000), "width": 64, "height": 64}
        robot.frame(message, event=H264_EVENT)
        error = robot.next("data_error")
        assert error["reason"] == "too_many_pixels" and "16000x16000" in error["error"], error
        robot.frame({"timestamp": 2, "frame": packets, "width": 64, "height": 64}, event=H264_EVENT)
        assert robot.next("results")["timestamp"] == 2  # the same stream at its true size is served
    finally:
        robot.close()


def test_a_flood_of_h264_keyframes_from_one_robot_holds_up_nobody_else(attack: Netapp) -> None:
    """The flood robot's own frames are dropped or refused (h264_overloaded) and counted; the good robot's
    results keep coming (checked by the `attack` fixture)."""
    pytest.importorskip("av")
    from netapp.client.h264 import H264Encoder

    width, height = 960, 540
    encoder = H264Encoder(width, height, {"g": "1"})  # every frame a keyframe
    rng = np.random.default_rng(0)
    keyframes = [encoder.encode(rng.integers(0, 255, (height, width, 3), np.uint8))[0] for _ in range(3)]
    robot = RawRobot(attack.url)
    try:
        assert robot.init()[0]
        sent = 40  # back to back, as fast as the client sends them
        for i in range(sent):
            robot.frame({"timestamp": i, "frame": keyframes[i % 3], "width": width, "height": height}, event=H264_EVENT)
        deadline = time.monotonic() + 30
        while True:  # every frame of the flood is accounted for: a result, dropped, or refused
            state = json.loads(robot.command({"cmd_type": 3, "clear_queue": False, "data": {}})[1])
            if state["received"] == sent and state["processed"] + state["dropped"] + state["rejected"] == sent:
                break
            assert time.monotonic() < deadline, state
            time.sleep(0.05)
    finally:
        robot.close()


def test_a_socketio_packet_announcing_a_million_attachments_closes_its_connection(attack: Netapp) -> None:
    robot = RawRobot(attack.url)
    closed = threading.Event()
    robot.sio.on("disconnect", lambda *reason: closed.set(), namespace=DATA_NAMESPACE)
    try:
        assert robot.init()[0]
        robot.sio.eio.send('51000000-/data,["image",{"_placeholder":true,"num":0}]')
        error = robot.next("data_error")
        assert error["reason"] == "packet_refused" and "1000000 binary attachments" in error["error"]
        assert closed.wait(10)
    finally:
        robot.close()


def test_a_socketio_packet_buffering_too_many_bytes_closes_its_connection(attack: Netapp) -> None:
    limit = Settings().transport_limit_bytes
    robot = RawRobot(attack.url)
    closed = threading.Event()
    robot.sio.on("disconnect", lambda *reason: closed.set(), namespace=DATA_NAMESPACE)
    try:
        assert robot.init()[0]
        placeholders = ",".join(f'{{"_placeholder":true,"num":{i}}}' for i in range(4))
        robot.sio.eio.send(f'54-/data,["image",[{placeholders}]]')
        chunk = b"\0" * (limit // 2 + 1)
        for _ in range(3):
            robot.sio.eio.send(chunk)
        error = robot.next("data_error")
        assert error["reason"] == "packet_refused" and f"over {limit} bytes" in error["error"]
        assert closed.wait(10)
    finally:
        robot.close()


def test_a_frames_robot_sending_garbage_holds_up_nobody_else(attack: Netapp) -> None:
    """The `frames` WebSocket (docs/protocol.md#bounds): random messages each get one error and the connection goes
    on; a picture too large is refused from its header; a message over the limit closes the connection (1009)."""
    robot = RawFramesRobot(attack.url)
    try:
        assert robot.init()["ok"] is True
        for _ in range(200):
            robot.send(os.urandom(64))
        reasons = [robot.next("error")["reason"] for _ in range(200)]  # one each (some H.264 ones say more)
        assert "unknown_kind" in reasons and all(isinstance(reason, str) and reason for reason in reasons)
        robot.frame(7, payload=jpeg_claiming(65500, 16000))
        assert robot.next("error")["reason"] == "too_many_pixels"
        robot.send(b"\x01\x01" + bytes(Settings().transport_limit_bytes))
        assert robot.closed.wait(10) and robot.close_code == 1009
    finally:
        robot.close()


def test_register_bodies_and_sessions_are_capped(attack: Netapp) -> None:
    url = attack.url
    big = requests.post(f"{url}/register", json={"args": {"x": "y" * 100_000}}, timeout=5)
    assert big.status_code == 413 and "65536-byte limit" in big.json()["error"]
    opened, refused = [], None
    for _ in range(MAX_SESSIONS + 2):
        r = requests.post(f"{url}/register", json={}, timeout=5)
        if r.status_code != 201:
            refused = r
            break
        opened.append(r.json()["session_id"])
    assert refused is not None and refused.status_code == 503, refused
    assert refused.json()["reason"] == "sessions_full" and int(refused.headers["Retry-After"]) > 0
    robot = RawRobot(url)  # Socket.IO INIT hears it too
    try:
        ok, message = robot.init()
        assert not ok and "limit of" in message
    finally:
        robot.close()
    for session_id in opened:
        unregister(url, session_id)
    assert requests.post(f"{url}/register", json={}, timeout=5).status_code == 201


def test_half_open_and_idle_connections_are_closed(attack: Netapp) -> None:
    host, port = attack.url.removeprefix("http://").split(":")
    robot = RawRobot(attack.url)  # a Socket.IO robot idle beside them is not a half-open connection
    assert robot.init()[0]
    idle = [socket.create_connection((host, int(port)), timeout=10) for _ in range(30)]
    half_head = [socket.create_connection((host, int(port)), timeout=10) for _ in range(10)]
    half_body = [socket.create_connection((host, int(port)), timeout=10) for _ in range(10)]
    session_id = register(attack.url)
    for sock in half_head:
        sock.sendall(b"POST /send_image HTTP/1.1\r\nHost: x\r\nContent-Type: image/jpeg\r\n")
    for sock in half_body:
        head = f"POST /send_image HTTP/1.1\r\nHost: x\r\nX-Session-Id: {session_id}\r\nContent-Type: image/jpeg\r\n"
        sock.sendall(head.encode() + b"Content-Length: 100000\r\n\r\n" + make_jpeg()[:100])
    for sock in idle + half_head:  # closed by the server within the head timeout: recv sees the end
        assert sock.recv(1024) == b""
    for sock in half_body:
        reply = b""
        while chunk := sock.recv(4096):  # until the server closes the connection
            reply += chunk
        assert reply.startswith(b"HTTP/1.1 408") and b"did not arrive" in reply, reply[:200]
    for sock in idle + half_head + half_body:
        sock.close()
    unregister(attack.url, session_id)
    try:
        assert json.loads(robot.command({"cmd_type": 3, "data": {}})[1])["received"] == 0
    finally:
        robot.close()


def test_a_request_head_over_its_limit_is_refused(attack: Netapp) -> None:
    host, port = attack.url.removeprefix("http://").split(":")
    limit = MAX_HEAD_BYTES
    big_header = b"X-Junk: " + b"a" * (limit // 4) + b"\r\n"
    with socket.create_connection((host, int(port)), timeout=10) as sock:  # sent in pieces, never complete
        sock.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
        for _ in range(5):
            sock.sendall(big_header)
        reply = b""
        while chunk := sock.recv(4096):
            reply += chunk
        assert reply.startswith(b"HTTP/1.1 400"), reply[:200]
    assert requests.get(f"{attack.url}/healthz", headers={"X-Fine": "a" * (limit // 2)}, timeout=5).ok
    # a whole head over the bound in one piece, and one header never finished, sent in pieces: refused too
    one_header = [b"X-Junk: " + b"a" * (limit // 4)] + [b"a" * (limit // 4)] * 4
    for pieces in ([b"GET /healthz HTTP/1.1\r\nHost: x\r\n" + big_header * 5 + b"\r\n"], one_header):
        with socket.create_connection((host, int(port)), timeout=10) as sock:
            if pieces is one_header:
                sock.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
            for piece in pieces:
                sock.sendall(piece)
            reply = b""
            while chunk := sock.recv(4096):
                reply += chunk
            assert reply.startswith(b"HTTP/1.1 400") and b"request head" in reply, reply[:300]


def test_a_body_in_the_same_packet_as_its_head_is_not_counted_as_head(attack: Netapp) -> None:
    """The head's bound counts the head only: a frame of several times the bound, sent with its head at once, is
    taken (and the connection stays up for the next request on it)."""
    host, port = attack.url.removeprefix("http://").split(":")
    session_id = register(attack.url)
    noise = np.random.default_rng(0).integers(0, 256, (480, 640, 3), np.uint8)
    jpeg = cv2.imencode(".jpg", noise)[1].tobytes()  # noise does not compress: several times the head's bound
    assert len(jpeg) > 4 * MAX_HEAD_BYTES
    head = (
        f"POST /send_image?wait=true HTTP/1.1\r\nHost: x\r\nX-Session-Id: {session_id}\r\n"
        f"Content-Type: image/jpeg\r\nContent-Length: {len(jpeg)}\r\n\r\n"
    ).encode()
    with socket.create_connection((host, int(port)), timeout=10) as sock:
        for _ in range(2):
            sock.sendall(head + jpeg)
            reply = b""
            while b"\r\n\r\n" not in reply or not reply.rstrip().endswith(b"}"):
                chunk = sock.recv(65536)
                assert chunk, reply[:200]
                reply += chunk
            assert reply.startswith(b"HTTP/1.1 200"), reply[:200]
    unregister(attack.url, session_id)


def test_an_aborted_upload_is_one_log_line(attack: Netapp) -> None:
    host, port = attack.url.removeprefix("http://").split(":")
    session_id = register(attack.url)
    with socket.create_connection((host, int(port)), timeout=10) as sock:
        head = f"POST /send_image HTTP/1.1\r\nHost: x\r\nX-Session-Id: {session_id}\r\nContent-Type: image/jpeg\r\n"
        sock.sendall(head.encode() + b"Content-Length: 100000\r\n\r\n" + make_jpeg()[:100])
        time.sleep(0.2)  # the route is reading the body: let it read the first bytes before the client leaves
    deadline = time.monotonic() + 10
    while "went away during its upload" not in attack.log.read_text() and time.monotonic() < deadline:
        time.sleep(0.05)
    text = attack.log.read_text()
    assert "went away during its upload" in text and "ClientDisconnect" not in text and "Traceback" not in text
    unregister(attack.url, session_id)


def test_a_flood_of_waiting_requests_holds_up_nobody_else(attack: Netapp) -> None:
    url = attack.url
    sessions = [register(url) for _ in range(4)]
    with ThreadPoolExecutor(64) as pool:
        replies = list(pool.map(lambda s: post_jpeg(url, s, make_jpeg()), sessions * 25))
    statuses = {r.status_code for r in replies}
    assert statuses <= {200, 409, 503} and 200 in statuses, statuses  # results, superseded, or over the cap
    for reply in replies:
        if reply.status_code == 503:
            assert reply.json()["reason"] == "too_many_waiting" and reply.headers["Retry-After"] == "1"
    for session_id in sessions:
        unregister(url, session_id)


def test_waiting_requests_are_capped_per_session_and_in_all(serve) -> None:
    from tests.support.processors import GatedProcessor

    processor = GatedProcessor()
    server = serve(processor, Settings(max_waiting=3, max_waiting_per_session=2, queue_size=4, lanes=1))
    url, state = server.url, server.app.other_asgi_app.state.netapp
    one, two = register(url), register(url)
    with ThreadPoolExecutor(4) as pool:
        held = [pool.submit(post_jpeg, url, one, make_jpeg())]
        assert processor.entered.acquire(timeout=10)  # the first frame is in process(): the rest wait behind it
        held += [pool.submit(post_jpeg, url, one, make_jpeg()), pool.submit(post_jpeg, url, two, make_jpeg())]
        deadline = time.monotonic() + 10
        while state.waiting < 3:  # polled with a deadline: all three wait for their result
            assert time.monotonic() < deadline
            time.sleep(0.01)
        per_session = post_jpeg(url, one, make_jpeg())
        assert per_session.status_code == 503 and "2 per session" in per_session.json()["error"]
        assert per_session.headers["Retry-After"] == "1"
        in_all = post_jpeg(url, register(url), make_jpeg())
        assert in_all.json()["reason"] == "too_many_waiting" and "3 in all" in in_all.json()["error"]
        processor.gate.set()
        assert [f.result().status_code for f in held] == [200, 200, 200]


# the last two: integers, but past 64 bits (the frames header's timestamp, and what a result's JSON carries)
@pytest.mark.parametrize("timestamp", ["--5", "\u00b2", "1" * 4301, "12a", "", "+5", "9" * 20, "-9223372036854775809"])
def test_a_malformed_x_timestamp_is_a_422(attack: Netapp, timestamp: str) -> None:
    session_id = register(attack.url)
    reply = post_jpeg(attack.url, session_id, make_jpeg(), **{"X-Timestamp": timestamp.encode("latin-1")})
    assert reply.status_code == 422 and reply.json()["reason"] == "bad_timestamp", reply.text
    unregister(attack.url, session_id)


def test_socketio_events_with_a_wrong_number_of_arguments_get_an_error(attack: Netapp) -> None:
    robot = RawRobot(attack.url)
    try:
        assert robot.init()[0]
        for args in ((), ({"cmd_type": 3}, {"cmd_type": 3})):
            robot.sio.emit("command", args, namespace=CONTROL_NAMESPACE)
            assert f"got {len(args)}" in robot.next("command_error")["error"]
        for args in ((), ({"timestamp": 1, "frame": make_jpeg()}, 2)):
            robot.sio.emit("image", args, namespace=DATA_NAMESPACE)
            error = robot.next("data_error")
            assert error["reason"] == "malformed" and f"got {len(args)}" in error["error"]
    finally:
        robot.close()


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt is glibc's")
def test_the_netapp_set_its_malloc_thresholds(netapp: Netapp) -> None:
    """`netapp serve` maps large blocks on their own from the start (what keeps the H.264 flood's RSS bounded;
    tests/netapp/server/test_allocator.py shows what the settings do)."""
    line = f"malloc: M_MMAP_THRESHOLD {MMAP_THRESHOLD_BYTES}, M_TRIM_THRESHOLD {TRIM_THRESHOLD_BYTES}"
    assert line in netapp.log.read_text()


def test_one_opencv_thread_decodes_a_picture(netapp: Netapp) -> None:
    """The lanes run side by side; OpenCV's own pool on top of them only cost CPU (`--opencv-threads`)."""
    assert "OpenCV: 1 thread(s) for one picture's decoding and resizing" in netapp.log.read_text()


def test_the_netapp_memory_stayed_bounded(netapp: Netapp) -> None:
    """Last in this module: the peak over every attack above."""
    assert netapp.process.poll() is None, "the netapp died"
    peak = rss_bytes(netapp.process.pid, peak=True)
    print(f"netapp peak RSS over the attacks: {peak / 2**20:.0f} MiB")
    assert peak < RSS_BOUND, f"peak RSS {peak / 2**20:.0f} MiB"
