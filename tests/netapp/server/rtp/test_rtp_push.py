"""H.264 over RTP pushed to a session's UDP port, end to end: a real netapp on loopback, a `frames` robot opening
the session, Debian's GStreamer (gst-launch-1.0) as the robot's own sender, results back on the robot's WebSocket;
hostile datagrams from strangers, each dropped and counted while the robot's results go on."""

from __future__ import annotations

import queue
import socket
import threading

import pytest
import requests
import socketio

from netapp.protocol import (
    COMMAND_EVENT,
    CONTROL_NAMESPACE,
    DATA_NAMESPACE,
    H264_KEYFRAME_REASONS,
    RESULTS_EVENT,
    SESSION_INFO_EVENT,
)
from netapp.rtp.packet import build, is_rtcp
from netapp.serve_process import free_port
from netapp.server.settings import Settings
from tests.netapp.server.test_frames import metric
from tests.support.gst_rtp_sender import GstRtpSender, gst_problem
from tests.support.polling import wait_until
from tests.support.raw_frames_robot import RawFramesRobot
from tests.support.rtp_attacks import ABSURD_RTP_ARGS, flood, malformed, send_all


@pytest.fixture(scope="module")
def gstreamer() -> None:
    pytest.importorskip("av", reason="PyAV is not installed: pip install 'netapp-toolkit[h264]'")
    problem = gst_problem()
    if problem:
        pytest.skip(problem)


def rtp_settings(count: int = 4, **more) -> Settings:
    first = free_port()
    return Settings(lanes=1, rtp_ports=range(first, first + count), **more)


@pytest.fixture
def robots():
    started: list[RawFramesRobot] = []

    def connect(url: str) -> RawFramesRobot:
        started.append(RawFramesRobot(url))
        return started[-1]

    yield connect
    for robot in started:
        robot.close()


def dropped(url: str, reason: str) -> float:
    return metric(url, f'netapp_rtp_dropped_total{{reason="{reason}"}}')


def test_a_gstreamer_sender_gets_results_on_the_robots_websocket(gstreamer, serve, tiny_detector, robots):
    server = serve(tiny_detector, rtp_settings())
    robot = robots(server.url)
    ack = robot.init(robot_id="gst", rtp={"payload_type": 96})
    assert ack["ok"], ack
    rtp = ack["rtp"]
    assert rtp["port"] in server.app.frames.commands.rtp.pool.ports and "m=video" in rtp["sdp"] and rtp["ssrc"] >= 0
    with GstRtpSender(rtp["port"], rtp["ssrc"]):
        first = robot.next("results", timeout=30)
        second = robot.next("results", timeout=10)
    assert "detections" in first and second["timestamp"] > first["timestamp"]  # RTP timestamps, unwrapped
    assert metric(server.url, 'netapp_frames_processed_total{transport="rtp"}') >= 2


def test_strangers_and_hostile_datagrams_are_dropped_and_counted_while_the_robot_goes_on(
    gstreamer, serve, tiny_detector, robots
):
    server = serve(tiny_detector, rtp_settings())
    robot = robots(server.url)
    rtp = robot.init(robot_id="gst", rtp={})["rtp"]
    port, ssrc = rtp["port"], rtp["ssrc"]
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        with GstRtpSender(port, ssrc):
            robot.next("results", timeout=30)  # the sender is bound now
            good = build(b"\x65\x88", payload_type=96, sequence=1, timestamp=1, ssrc=ssrc, marker=True)
            for datagram in (good, b"\x00" * 12, b"\xff" * 3000):
                stranger.sendto(datagram, ("127.0.0.1", port))
            wait_until(lambda: dropped(server.url, "stranger") >= 3, 10, "the stranger's datagrams counted")
            before = metric(server.url, 'netapp_frames_processed_total{transport="rtp"}')
            wait_until(
                lambda: metric(server.url, 'netapp_frames_processed_total{transport="rtp"}') >= before + 3,
                15,
                "the robot's results going on",
            )
        stranger_port = stranger.getsockname()[1]
        (stream,) = server.app.frames.commands.rtp.streams.values()
        assert stream.flow.sender is not None and stream.flow.sender[1] != stranger_port
    finally:
        stranger.close()


class LossyRelay:
    """A UDP relay between the sender and the netapp that drops the datagrams `drop` picks (their 0-based index),
    and keeps what the netapp sends back to it (RTCP, with rtcp-mux)."""

    def __init__(self, target: tuple[str, int], drop) -> None:
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind(("127.0.0.1", 0))
        self.socket.settimeout(0.2)
        self.target, self.drop = target, drop
        self.back: list[bytes] = []
        self.sender: tuple[str, int] | None = None
        self.count = 0
        self.running = True
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    @property
    def port(self) -> int:
        return self.socket.getsockname()[1]

    def _run(self) -> None:
        while self.running:
            try:
                data, addr = self.socket.recvfrom(2048)
            except (TimeoutError, OSError):
                continue
            if addr == self.target:
                self.back.append(data)
                continue
            index, self.count = self.count, self.count + 1
            if not self.drop(index):
                self.socket.sendto(data, self.target)

    def close(self) -> None:
        self.running = False
        self.thread.join(5)
        self.socket.close()


def test_a_lost_packet_skips_pictures_asks_for_a_keyframe_and_never_reaches_the_decoder_damaged(
    gstreamer, serve, tiny_detector, robots
):
    server = serve(tiny_detector, rtp_settings())
    robot = robots(server.url)
    rtp = robot.init(robot_id="lossy", rtp={"rtcp_mux": True})["rtp"]
    relay = LossyRelay(("127.0.0.1", rtp["port"]), lambda index: index in (40, 41))
    try:
        with GstRtpSender(relay.port, rtp["ssrc"], key_int=10):
            error = robot.next("error", timeout=30)
            assert error["reason"] in H264_KEYFRAME_REASONS and error["reason"] == "h264_missing_packet"
            wait_until(lambda: any(is_rtcp(d) and d[1] == 206 for d in relay.back), 10, "an RTCP PLI at the sender")
            after = robot.next("results", timeout=15)  # results resume at the next keyframe
    finally:
        relay.close()
    assert after["timestamp"] > 0
    assert dropped(server.url, "gap") >= 1
    assert metric(server.url, "netapp_rtp_keyframe_requests_total") >= 1
    for reason in ("h264_missing_packet", "h264_decode_error"):  # the decoder never saw a damaged picture
        assert metric(server.url, f'netapp_frames_rejected_total{{transport="rtp",reason="{reason}"}}') == 0


def test_hostile_rtp_is_bounded_and_counted_and_another_robot_is_untouched(gstreamer, serve, tiny_detector, robots):
    server = serve(tiny_detector, rtp_settings(rtp_max_packets_per_s=200))
    victim = robots(server.url)
    rtp = victim.init(robot_id="victim", rtp={})["rtp"]
    with GstRtpSender(rtp["port"], rtp["ssrc"]):
        victim.next("results", timeout=30)
        attacker = robots(server.url)
        theirs = attacker.init(robot_id="attacker", rtp={})["rtp"]
        target = ("127.0.0.1", theirs["port"])
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sps = build(b"\x67\x42", payload_type=96, sequence=0, timestamp=0, ssrc=theirs["ssrc"], marker=True)
            send_all([sps], target, sock)  # binds the attacker's address to its session
            bad = malformed(theirs["ssrc"])
            send_all(bad, target, sock)
            # sequence numbers 30,000 ahead each time: the stream starts again at each (bounded work), counted
            jumps = [
                build(b"\x41", payload_type=96, sequence=30_000 * i, timestamp=i, ssrc=theirs["ssrc"], marker=True)
                for i in range(1, 21)
            ]
            send_all(jumps, target, sock)
            wait_until(lambda: metric(server.url, "netapp_rtp_restarts_total") >= 19, 10, "the jumps counted")
            wrong = build(b"\x65", payload_type=100, sequence=9, timestamp=9, ssrc=theirs["ssrc"], marker=True)
            send_all([wrong] * 50, target, sock)
            wait_until(lambda: dropped(server.url, "wrong_payload_type") >= 50, 10, "wrong payload types counted")
            send_all([wrong] * 400, target, sock)  # past its 200 packets a second (and the burst of one second)
            wait_until(lambda: dropped(server.url, "flood") > 0, 10, "the robot's own flood cut at its rate")
        finally:
            sock.close()
        assert dropped(server.url, "malformed") + dropped(server.url, "too_large") >= len(bad)
        sent = flood(("127.0.0.1", rtp["port"]), 0.5, ssrc=rtp["ssrc"])  # a stranger, with the victim's SSRC even
        wait_until(lambda: dropped(server.url, "stranger") > 0, 10, "the stranger's flood counted")
        assert dropped(server.url, "stranger") <= sent
        for args in ABSURD_RTP_ARGS:
            refused = robots(server.url).init(robot_id="absurd", rtp=args)
            assert not refused["ok"] and refused["reason"] == "bad_rtp" and len(refused["message"]) < 300
        before = metric(server.url, 'netapp_frames_processed_total{transport="rtp"}')
        wait_until(
            lambda: metric(server.url, 'netapp_frames_processed_total{transport="rtp"}') >= before + 3,
            15,
            "the victim's results going on",
        )
    assert metric(server.url, 'netapp_rtp_sessions_refused_total{reason="bad_rtp"}') == len(ABSURD_RTP_ARGS)
    assert server.app.frames.commands.rtp.pool.free == 2  # the absurd INITs opened nothing


def test_sessions_past_the_port_range_are_refused_and_a_port_comes_back_when_its_robot_leaves(
    gstreamer, serve, tiny_detector, robots
):
    server = serve(tiny_detector, rtp_settings(count=1))
    first = robots(server.url)
    assert first.init(robot_id="a", rtp={})["ok"]
    second = robots(server.url)
    refused = second.init(robot_id="b", rtp={})
    assert not refused["ok"] and refused["reason"] == "rtp_ports_full" and refused["retry_after_s"] == 5
    assert server.app.services.sessions.get(refused["session_id"]) is None
    first.close()
    wait_until(lambda: server.app.frames.commands.rtp.pool.free == 1, 10, "the port given back")
    assert robots(server.url).init(robot_id="c", rtp={})["ok"]


def test_a_socketio_robot_opens_an_rtp_session_and_gets_its_results_on_data(gstreamer, serve, tiny_detector):
    server = serve(tiny_detector, rtp_settings())
    infos: queue.Queue = queue.Queue()
    results: queue.Queue = queue.Queue()
    client = socketio.Client(reconnection=False)
    client.on(SESSION_INFO_EVENT, infos.put, namespace=CONTROL_NAMESPACE)
    client.on(RESULTS_EVENT, results.put, namespace=DATA_NAMESPACE)
    client.connect(server.url, namespaces=[DATA_NAMESPACE, CONTROL_NAMESPACE], wait_timeout=10)
    try:
        command = {"cmd_type": 1, "clear_queue": False, "data": {"robot_id": "sio", "rtp": {}}}
        ok, message = client.call(COMMAND_EVENT, command, namespace=CONTROL_NAMESPACE, timeout=10)
        assert ok and "RTP" in message  # the ack keeps 5G-ERA's (ok, message)
        rtp = infos.get(timeout=5)["rtp"]
        with GstRtpSender(rtp["port"], rtp["ssrc"]):
            assert "detections" in results.get(timeout=30)
    finally:
        client.disconnect()
    wait_until(lambda: server.app.frames.commands.rtp.pool.free == 4, 10, "the port given back on disconnect")


def test_an_http_robot_registers_for_rtp_and_polls_its_results(gstreamer, serve, tiny_detector):
    server = serve(tiny_detector, rtp_settings(count=1))
    absurd = requests.post(f"{server.url}/register", json={"args": {"rtp": {"payload_type": 5}}}, timeout=10)
    assert absurd.status_code == 422 and absurd.json()["reason"] == "bad_rtp"
    assert server.app.services.sessions.count("http") == 0  # refused before any session opened
    registered = requests.post(f"{server.url}/register", json={"robot_id": "h", "args": {"rtp": {}}}, timeout=10)
    assert registered.status_code == 201, registered.text
    body = registered.json()
    session, rtp = {"X-Session-Id": body["session_id"]}, body["rtp"]
    full = requests.post(f"{server.url}/register", json={"args": {"rtp": {}}}, timeout=10)
    assert full.status_code == 503 and full.json()["reason"] == "rtp_ports_full" and "Retry-After" in full.headers

    def polled() -> list:
        return requests.get(f"{server.url}/results", headers=session, timeout=10).json()["results"]

    with GstRtpSender(rtp["port"], rtp["ssrc"]):
        results = wait_until(polled, 30, "results to poll")
    assert "detections" in results[0]
    assert requests.post(f"{server.url}/unregister", headers=session, timeout=10).status_code == 200
    assert server.app.frames.commands.rtp.pool.free == 1  # the port went with the session
