"""`netapp stream --transport rtp`: the robot client's H.264 over RTP/UDP (PyAV, the project's packetiser) to a real
netapp with --rtp-ports, its session and results on the frames WebSocket."""

from __future__ import annotations

import json
import socket
import threading
import time

import cv2
import numpy as np
import pytest

from netapp.cli import main as netapp_main
from netapp.client import NetAppClient
from netapp.client.errors import NetAppRefused
from netapp.client.transports.rtp import RtpTransport
from netapp.rtp.packet import RESULT_APP, parse_app
from netapp.serve_process import free_port
from netapp.server.settings import Settings
from tests.netapp.server.test_frames import metric
from tests.netapp.test_cli import netapp


@pytest.fixture(scope="module", autouse=True)
def pyav() -> None:
    pytest.importorskip("av", reason="PyAV is not installed: pip install 'netapp-toolkit[h264]'")


def rtp_server(serve, processor):
    first = free_port()
    return serve(processor, Settings(lanes=1, rtp_ports=range(first, first + 2)))


def test_netapp_stream_sends_rtp_and_gets_every_result(tmp_path, serve, tiny_detector):
    server = rtp_server(serve, tiny_detector)
    image = tmp_path / "frame.jpg"
    cv2.imwrite(str(image), np.full((240, 320, 3), 90, np.uint8))
    args = ["--transport", "rtp", "--source", str(image), "--fps", "10", "--duration", "2", "--json"]
    out = netapp("stream", server.url, *args)
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout)
    assert summary["results"] >= 15 and summary["errors"] == 0 and summary["lost"] == 0
    assert metric(server.url, 'netapp_frames_processed_total{transport="rtp"}') == summary["results"]
    assert server.app.frames.commands.rtp.pool.free == 2  # the session's port came back when the robot left
    counters = summary["transport_counters"][server.url]  # the robot's side, by netapp
    assert counters["packets"] >= summary["frames_sent"] and counters["reader_error"] is None
    assert counters["results_udp"] + counters["results_websocket"] == summary["results"]


class AllLost:
    """A UDP socket on a link that carries nothing out."""

    def __init__(self, family: int, kind: int) -> None:
        self.socket = socket.socket(family, kind)

    def sendto(self, data: bytes, target) -> int:
        return len(data)

    def __getattr__(self, name: str):
        return getattr(self.socket, name)


def test_a_stream_without_a_result_says_why_in_one_line(tmp_path, serve, tiny_detector, monkeypatch, capsys):
    monkeypatch.setattr(RtpTransport, "udp_socket", staticmethod(AllLost))
    server = rtp_server(serve, tiny_detector)
    image = tmp_path / "frame.jpg"
    cv2.imwrite(str(image), np.full((240, 320, 3), 90, np.uint8))
    args = ["--transport", "rtp", "--source", str(image), "--fps", "10", "--duration", "0.5", "--json"]
    assert netapp_main(["stream", server.url, *args]) == 1
    out = capsys.readouterr()
    summary = json.loads(out.out)
    assert summary["results"] == 0 and summary["transport_counters"][server.url]["packets"] >= 2
    line = out.err.strip().splitlines()[-1]
    assert line.startswith("error: no results: ") and f"{server.url}: packets " in line and "nacked 0" in line


def test_a_netapp_without_rtp_ports_refuses_in_one_line_naming_the_flag(tiny_server):
    with pytest.raises(NetAppRefused, match="--rtp-ports"):
        NetAppClient(tiny_server.url, transport="rtp", connect_timeout_s=5).connect()


def test_rtp_carries_h264_only():
    with pytest.raises(ValueError, match="H.264 only"):
        NetAppClient("http://127.0.0.1:9", transport="rtp", codec="jpeg")


class LossyUdp:
    """A real UDP socket that loses every `every`th datagram it is given, as a lossy link would."""

    def __init__(self, family: int, kind: int, every: int = 25, resends_lost: bool = False) -> None:
        self.socket = socket.socket(family, kind)
        self.every, self.count, self.lost, self.resends_lost = every, 0, 0, resends_lost

    def sendto(self, data: bytes, target) -> int:
        self.count += 1
        resend = threading.current_thread().name == "netapp-rtcp"  # the transport's NACK reader sends again
        if self.count % self.every == 0 or (resend and self.resends_lost):
            self.lost += 1
            return len(data)
        return self.socket.sendto(data, target)

    def settimeout(self, seconds: float) -> None:
        self.socket.settimeout(seconds)

    def recvfrom(self, size: int):
        return self.socket.recvfrom(size)

    def close(self) -> None:
        self.socket.close()


@pytest.mark.parametrize("resends_lost", [False, True], ids=["resent", "resends-lost-too"])
def test_lost_packets_are_sent_again_or_cost_frames_until_a_keyframe(serve, tiny_detector, monkeypatch, resends_lost):
    links: list[LossyUdp] = []

    def lossy(family: int, kind: int) -> LossyUdp:
        links.append(LossyUdp(family, kind, resends_lost=resends_lost))
        return links[-1]

    monkeypatch.setattr(RtpTransport, "udp_socket", staticmethod(lossy))
    server = rtp_server(serve, tiny_detector)
    sent = 0
    with NetAppClient(server.url, transport="rtp", full_frames=True, result_timeout_s=30) as client:
        deadline = time.monotonic() + 6
        while time.monotonic() < deadline:  # 10 fps of a moving square: a keyframe is a few packets
            frame = np.full((240, 320, 3), 90, np.uint8)
            frame[60:180, 10 * (sent % 20) : 10 * (sent % 20) + 120] = (30, 200, 60)
            client.send(frame)
            sent += 1
            time.sleep(0.1)  # the robot's camera rate
        stats = client.stats
    assert links and links[0].lost >= 2
    assert metric(server.url, "netapp_rtp_nacked_total") >= 1  # each loss asked for again (NACK)
    if not resends_lost:  # sent again from the client's buffer: nearly every picture answered
        assert stats.results >= sent - 6 and metric(server.url, 'netapp_rtp_dropped_total{reason="gap"}') == 0
    else:  # given up after the hold: the pictures until a keyframe are skipped, each told, the encoder restarted
        assert metric(server.url, 'netapp_rtp_dropped_total{reason="gap"}') >= 1 and stats.errors >= 1
        # every frame answered: a result, or an error for a skipped picture (none waited for the 30 s timeout,
        # which would have stalled the robot at its 2 frames in flight)
        assert stats.results >= sent // 2 and stats.results + stats.errors + stats.dropped_client >= sent - 2
    for reason in ("h264_missing_packet", "h264_decode_error"):  # the decoder never saw a damaged picture
        assert metric(server.url, f'netapp_frames_rejected_total{{transport="rtp",reason="{reason}"}}') == 0


class FirstPacketLost(LossyUdp):
    """A real UDP socket that loses the first datagram it sends (the stream's first packet: its SPS) and no other."""

    def __init__(self, family: int, kind: int) -> None:
        super().__init__(family, kind, every=10**9)

    def sendto(self, data: bytes, target) -> int:
        if self.count == 0:
            self.count, self.lost = 1, 1
            return len(data)
        return super().sendto(data, target)


def test_a_stream_whose_first_packet_is_lost_starts_again_at_a_keyframe(serve, tiny_detector, monkeypatch):
    # The first packet lost is no gap to the netapp (nothing came before it): its first keyframe came without its
    # SPS. It is skipped and told (the robot's encoder restarts), not decoded without a size: that refused every
    # picture until the encoder's own next keyframe (25 frames), a round with no result at all.
    links: list[FirstPacketLost] = []

    def first_lost(family: int, kind: int) -> FirstPacketLost:
        links.append(FirstPacketLost(family, kind))
        return links[-1]

    monkeypatch.setattr(RtpTransport, "udp_socket", staticmethod(first_lost))
    server = rtp_server(serve, tiny_detector)
    with NetAppClient(server.url, transport="rtp", full_frames=True, result_timeout_s=30) as client:
        for sent in range(12):  # fewer than the encoder's keyframe interval
            frame = np.full((240, 320, 3), 90, np.uint8)
            frame[60:180, 10 * sent : 10 * sent + 120] = (30, 200, 60)
            client.send(frame)
            time.sleep(0.1)  # the robot's camera rate
        client.wait_idle(10)
        stats, counters = client.stats, client.transport_report()[server.url]
    assert links[0].lost == 1
    assert stats.results >= 12 - 3 and stats.results + stats.errors + stats.dropped_client == 12
    assert counters["plis"] >= 1  # the netapp asked for a keyframe too
    assert metric(server.url, 'netapp_rtp_dropped_total{reason="incomplete"}') == 1
    assert metric(server.url, 'netapp_frames_rejected_total{transport="rtp",reason="missing_size"}') == 0


class ResultsSeen(LossyUdp):
    """A real UDP socket that loses nothing it sends, and counts (or loses) the result datagrams it receives."""

    def __init__(self, family: int, kind: int, lose_results: bool) -> None:
        super().__init__(family, kind, every=10**9)
        self.lose_results, self.results = lose_results, 0

    def recvfrom(self, size: int):
        while True:
            data, sender = self.socket.recvfrom(size)
            if parse_app(data, RESULT_APP) is None:
                return data, sender
            self.results += 1
            if not self.lose_results:
                return data, sender


@pytest.mark.parametrize("lose_results", [False, True], ids=["datagrams-arrive", "datagrams-lost"])
def test_results_come_back_over_udp_too_and_each_is_delivered_once(serve, tiny_detector, monkeypatch, lose_results):
    links: list[ResultsSeen] = []

    def seen(family: int, kind: int) -> ResultsSeen:
        links.append(ResultsSeen(family, kind, lose_results))
        return links[-1]

    monkeypatch.setattr(RtpTransport, "udp_socket", staticmethod(seen))
    server = rtp_server(serve, tiny_detector)
    timestamps = []
    with NetAppClient(server.url, transport="rtp", full_frames=True, result_timeout_s=30) as client:
        for sent in range(20):
            frame = np.full((240, 320, 3), 90, np.uint8)
            frame[60:180, 10 * sent : 10 * sent + 120] = (30, 200, 60)
            client.send(frame)
            timestamps += [r.timestamp for r in client.results(timeout=0)]
            time.sleep(0.1)  # the robot's camera rate
        client.wait_idle(10)
        timestamps += [r.timestamp for r in client.results(timeout=0)]
        stats, counters = client.stats, client.transport_report()[server.url]
    processed = metric(server.url, 'netapp_frames_processed_total{transport="rtp"}')
    assert metric(server.url, 'netapp_rtp_results_udp_total{outcome="sent"}') == processed >= 18
    assert links[0].results >= processed - 1  # each result's datagram came (the last may still be on its way)
    # Each frame answered once, whichever copy came first (a lost datagram costs nothing: the WebSocket's counts)
    assert len(timestamps) == len(set(timestamps)) == stats.results == processed
    by_path = counters["results_udp"], counters["results_websocket"]  # on loopback, either copy may come first
    assert sum(by_path) == processed and (by_path[0] == 0 if lose_results else by_path[0] > 0)
