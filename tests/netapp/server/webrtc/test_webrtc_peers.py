"""WebRTC end to end: a real netapp on loopback (uvicorn, onnxruntime with YOLOX-Nano), aiortc robots
(`netapp.client.webrtc.WebRtcClient`, what `netapp stream --transport webrtc` uses) sending the shared media as a video
track, results back on the data channel; hostile offers refused with their reason and counted while a streaming robot
goes on; newest-only under a slow model."""

from __future__ import annotations

import json
import threading
import time

import cv2
import pytest
import requests

from netapp.server.connection import Connection
from netapp.server.settings import Settings
from netapp.server.webrtc.peers import Peer
from tests.netapp.server.test_frames import metric
from tests.support.polling import wait_until
from tests.support.processors import SlowProcessor
from tests.support.sdp_attacks import BROKEN, foreign_candidates

pytest.importorskip("aiortc", reason="aiortc is not installed: pip install 'netapp-toolkit[webrtc]'")

from netapp.client.webrtc import WebRtcClient  # noqa: E402

LOOPBACK = ("127.0.0.1",)  # aioice offers no loopback candidate unless told (netapp.webrtc_ice)
PERSON, DOG = 0, 16
GOOD_SDP = "v=0\r\no=- 1 2 IN IP4 127.0.0.1\r\ns=-\r\nt=0 0\r\nm=video 9 UDP/TLS/RTP/SAVPF 96\r\n"


class Streamer:
    """A robot sending `picture` at `fps` over WebRTC until closed."""

    def __init__(self, url: str, picture, fps: float = 10.0, robot_id: str = "webrtc-bot") -> None:
        self.client = WebRtcClient(url, robot_id=robot_id, ice_addresses=LOOPBACK)
        self.client.connect()
        self.picture, self.period = picture, 1 / fps
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.wait(self.period):  # the robot's frame rate
            self.client.send(self.picture)

    def results(self) -> list:
        return list(self.client.results(timeout=0))

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        self.client.close()


@pytest.fixture(scope="module")
def detector(real_model_path):
    from netapp.models import Detector, DetectorConfig

    return Detector(DetectorConfig(str(real_model_path)))


@pytest.fixture(scope="module")
def dog(media_dir):
    return cv2.imread(str(media_dir / "dog.jpg"))


def refused(url: str, reason: str) -> float:
    return metric(url, f'netapp_webrtc_refused_total{{reason="{reason}"}}')


def test_a_robot_streams_over_webrtc_and_gets_boxes_on_the_data_channel(serve, detector, dog):
    server = serve(detector, Settings(lanes=1))
    robot = Streamer(server.url, dog)
    try:
        results = []
        wait_until(lambda: results.extend(robot.results()) or len(results) >= 5, 30, "results over WebRTC")
        found = {d["class"] for d in results[-1].detections}
        assert DOG in found, results[-1].detections  # the dog of the shared picture, found by YOLOX-Nano
        bbox = next(d["bbox"] for d in results[-1].detections if d["class"] == DOG)
        assert bbox[2] - bbox[0] > 100 and bbox[3] - bbox[1] > 100  # in the picture's own pixels
        assert all(r.latency_ms < 2000 for r in results[1:])  # each result mapped back to its own frame
        assert results[-1].breakdown is not None  # split with the netapp's stamps (bench.udp's tail table)
        assert metric(server.url, 'netapp_frames_processed_total{transport="webrtc"}') >= 5
        live = server.app.other_asgi_app.state.live
        (view,) = live.robots()  # a session like any robot's: on the live page
        assert view.session.label == "webrtc" and view.session.robot_id == "webrtc-bot"
        assert metric(server.url, "netapp_webrtc_peers") == 1
        plane = server.app.other_asgi_app.state.dataplane
        (connection,) = plane.connections("webrtc")  # the one connection type, its peer the wire's own part
        assert isinstance(connection, Connection) and isinstance(connection.wire, Peer)
        assert connection.session is view.session
        # each result on the reliable channel and on the one that never resends: the robot takes one of the two
        peer = connection.wire
        assert (peer.channel.ordered, peer.copy.ordered, peer.copy.maxRetransmits) == (False, False, 0)
        assert len({r.timestamp for r in results}) == len(results)
    finally:
        robot.close()
    wait_until(lambda: metric(server.url, "netapp_webrtc_peers") == 0, 15, "the peer to go")
    assert metric(server.url, 'netapp_active_sessions{transport="webrtc"}') == 0
    assert plane.connections("webrtc") == [] and connection.closed  # its session ended: so did its connection


def test_hostile_offers_are_refused_and_counted_while_a_robot_streams(serve, detector, dog):
    settings = Settings(lanes=1, webrtc_max_peers_per_client=2, webrtc_connect_timeout_s=1.0)
    server = serve(detector, settings)
    offer = server.url + "/webrtc/offer"
    robot = Streamer(server.url, dog)
    try:
        wait_until(lambda: robot.client.stats.results >= 3, 30, "the robot's results")
        huge = requests.post(offer, data=b'{"type":"offer","sdp":"' + b"v" * 200_000 + b'"}', timeout=10)
        assert huge.status_code == 413
        garbage = requests.post(offer, data=b"\x00\xffnot json", timeout=10)
        assert (garbage.status_code, garbage.json()["reason"]) == (400, "bad_sdp")
        m_lines = GOOD_SDP + "m=video 9 UDP/TLS/RTP/SAVPF 96\r\n" * 10
        many = requests.post(offer, json={"type": "offer", "sdp": m_lines}, timeout=10)
        assert (many.status_code, many.json()["reason"]) == (422, "too_many_media")
        unusable = requests.post(offer, json={"type": "offer", "sdp": GOOD_SDP}, timeout=10)  # no ICE, no DTLS
        assert (unusable.status_code, unusable.json()["reason"]) == (400, "bad_sdp")
        assert "could never connect" in unusable.json()["error"]

        # A real offer never completed: answered, then let go after the connect timeout, counted
        hanging = WebRtcClient(server.url, ice_addresses=LOOPBACK)
        hanging._thread.start()
        sdp = hanging._run(hanging._offer())
        answered = requests.post(offer, json={"type": "offer", "sdp": sdp}, timeout=10)
        assert answered.status_code == 200 and answered.json()["type"] == "answer"
        too_many = requests.post(offer, json={"type": "offer", "sdp": sdp}, timeout=10)  # this address holds 2
        assert (too_many.status_code, too_many.json()["reason"]) == (429, "client_peers_full")
        wait_until(lambda: refused(server.url, "connect_timeout") == 1, 10, "the unconnected peer to be let go")
        hanging.close()

        assert refused(server.url, "sdp_too_large") == 1
        assert refused(server.url, "bad_sdp") == 2
        assert refused(server.url, "too_many_media") == 1
        assert refused(server.url, "client_peers_full") == 1
        before = robot.client.stats.results
        wait_until(lambda: robot.client.stats.results >= before + 5, 20, "the robot's results to go on")
        assert robot.client.stats.errors == 0
        assert metric(server.url, "netapp_webrtc_peers") == 1  # the robot's only
    finally:
        robot.close()


def test_only_the_newest_picture_waits_for_a_slow_model(serve, dog):
    slow = SlowProcessor(0.3)
    slow.gate.set()
    server = serve(slow, Settings(lanes=1))
    robot = Streamer(server.url, dog, fps=15)
    try:
        results = []
        wait_until(lambda: results.extend(robot.results()) or len(results) >= 8, 30, "results from the slow model")
        skipped = metric(server.url, "netapp_webrtc_skipped_total") + metric(
            server.url, 'netapp_frames_dropped_total{transport="webrtc"}'
        )
        assert skipped >= 8  # 15 pictures a second against 3 answers: the rest were skipped and counted
        # Nothing queued behind the model: the latest answers are as fresh as the first ones, a model's turn or two
        latencies = [r.latency_ms for r in results[2:]]
        assert max(latencies) < 1500, latencies
        assert slow.calls <= len(results) + 3  # the model saw only the pictures whose answers came back (or will)
    finally:
        robot.close()


def test_without_the_extra_the_route_says_what_to_install(serve, tiny_detector):
    server = serve(tiny_detector)
    server.app.other_asgi_app.state.webrtc.available = False  # as where aiortc is not installed
    answer = requests.post(server.url + "/webrtc/offer", json={"type": "offer", "sdp": GOOD_SDP}, timeout=10)
    assert answer.status_code == 501
    assert "pip install 'netapp-toolkit[webrtc]'" in answer.json()["error"]
    assert refused(server.url, "no_aiortc") == 1


def test_netapp_stream_over_webrtc_writes_its_results(serve, detector, media_dir, tmp_path, capsys):
    from netapp.cli import main

    server = serve(detector, Settings(lanes=1))
    jsonl = tmp_path / "results.jsonl"
    argv = ["stream", server.url, "--transport", "webrtc", "--ice-address", "127.0.0.1", "--source"]
    argv += [str(media_dir / "pedestrians.avi"), "--duration", "3", "--jsonl", str(jsonl), "--json"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["transport"] == "webrtc" and summary["results"] >= 10
    records = [json.loads(line) for line in jsonl.read_text().splitlines()]
    assert len(records) == summary["results"]
    assert any(d["class"] == PERSON for r in records for d in r["detections"])
    assert all(r["latency_ms"] < 2000 for r in records[1:])


def test_a_netapp_with_a_token_takes_offers_only_with_it(serve, tiny_detector):
    from netapp.server.access import token_digest

    server = serve(tiny_detector, Settings(lanes=1, token_sha256=token_digest("s3cret")))
    offer = {"type": "offer", "sdp": GOOD_SDP}
    refused_401 = requests.post(server.url + "/webrtc/offer", json=offer, timeout=10)
    assert refused_401.status_code == 401
    page = requests.get(server.url + "/camera", timeout=10)  # the page itself is static: its offer carries the token
    assert page.ok and "camera.js" in page.text
    with_token = requests.post(
        server.url + "/webrtc/offer", json=offer, headers={"Authorization": "Bearer s3cret"}, timeout=10
    )
    assert with_token.status_code == 400  # past the token: this SDP is no usable offer


def test_pictures_over_max_pixels_are_refused_before_they_are_decoded(serve, detector, dog):
    height, width = dog.shape[:2]
    server = serve(detector, Settings(lanes=1, max_pixels=width * height - 1))
    robot = Streamer(server.url, dog)
    try:
        wait_until(lambda: robot.client.stats.errors >= 3, 30, "the refusals")
        assert robot.client.stats.results == 0
        assert "pixels is over this netapp's limit" in robot.client.stats.last_error
        rejected = 'netapp_frames_rejected_total{reason="too_many_pixels",transport="webrtc"}'
        assert metric(server.url, rejected) >= 3
        assert metric(server.url, 'netapp_frames_processed_total{transport="webrtc"}') == 0
        # the keyframes were read, not decoded: the pictures after each, which refer to it, were held back
        wait_until(lambda: metric(server.url, "netapp_webrtc_held_total") > 0, 10, "the pictures held back")
    finally:
        robot.close()


def test_offers_that_could_never_connect_are_refused_at_once_and_foreign_candidates_never_checked(serve, tiny_detector):
    server = serve(tiny_detector, Settings(lanes=1, webrtc_connect_timeout_s=30))
    offer = server.url + "/webrtc/offer"
    client = WebRtcClient(server.url, ice_addresses=LOOPBACK)
    client._thread.start()
    try:
        sdp = client._run(client._offer())
        for kind, change in BROKEN.items():
            started = time.monotonic()
            answer = requests.post(offer, json={"type": "offer", "sdp": change(sdp)}, timeout=10)
            assert (answer.status_code, answer.json()["reason"]) == (400, "bad_sdp"), (kind, answer.text)
            assert time.monotonic() - started < 2, kind  # refused at once, never a peer held till the timeout
        assert refused(server.url, "bad_sdp") == len(BROKEN) and metric(server.url, "netapp_webrtc_peers") == 0
        # 20 candidates at addresses the offer did not come from: answered, none of them ever checked
        answered = requests.post(offer, json={"type": "offer", "sdp": sdp + foreign_candidates(20)}, timeout=10)
        assert answered.status_code == 200
        assert metric(server.url, "netapp_webrtc_candidates_dropped_total") == 20
        [peer] = server.app.other_asgi_app.state.webrtc.peers
        transports = {t.receiver.transport.transport for t in peer.pc.getTransceivers()}
        remote = [c.ip for t in transports for c in t.getRemoteCandidates()]
        assert remote and set(remote) == {"127.0.0.1"}
    finally:
        client.close()


def test_the_robot_takes_the_first_copy_of_a_result_compressed_or_not():
    """The copy channel carries the result's JSON compressed (one SCTP packet); whichever copy comes second is
    dropped, and what does not inflate is ignored."""
    import json

    from netapp.rtp.results import compressed

    client = WebRtcClient("http://127.0.0.1:9")
    text = json.dumps({"event": "results", "data": {"timestamp": 9000, "detections": []}})
    client._message(compressed(text.encode()))
    client._message(text)
    client._message(b"not zlib")
    assert [r.message["timestamp"] for r in client.results(timeout=0)] == [9000]
    client.close()


async def test_a_results_copy_goes_twice_in_separate_packets():
    """The copy channel never resends, so the netapp sends its copy again COPY_AGAIN_S later (another SCTP packet):
    a result waits for the reliable channel's resending only when all three are lost."""
    import asyncio
    from types import SimpleNamespace

    from netapp.rtp.results import inflated
    from netapp.server.webrtc.peers import WebRtcPeers

    sent: dict[str, list] = {"reliable": [], "copy": []}
    second = asyncio.Event()

    class Channel:
        readyState, bufferedAmount = "open", 0

        def __init__(self, name: str) -> None:
            self.name = name

        def send(self, data: object) -> None:
            sent[self.name].append(data)
            if len(sent["copy"]) == 2:
                second.set()

    peer = SimpleNamespace(channel=Channel("reliable"), copy=Channel("copy"))
    peers = WebRtcPeers.__new__(WebRtcPeers)  # `_tell` reads only the dataplane's connection of the session
    peers.dataplane = SimpleNamespace(connection=lambda session_id: SimpleNamespace(wire=peer))
    text = json.dumps({"event": "results", "data": {"timestamp": 9000, "detections": []}})
    peers._tell(SimpleNamespace(id="s1"), text, copy=True)
    assert sent["reliable"] == [text] and len(sent["copy"]) == 1  # at once: the reliable one and a copy
    await asyncio.wait_for(second.wait(), 5)
    assert sent["copy"][0] == sent["copy"][1] and inflated(sent["copy"][1]) == text.encode()
