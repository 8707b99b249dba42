"""`netapp stream --transport rtp`: the robot client's H.264 over RTP/UDP (PyAV, the project's packetiser) to a real
netapp with --rtp-ports, its session and results on the frames WebSocket."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from netapp.client import NetAppClient
from netapp.client.errors import NetAppRefused
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
    assert server.app.frames.rtp.pool.free == 2  # the session's port came back when the robot left


def test_a_netapp_without_rtp_ports_refuses_in_one_line_naming_the_flag(tiny_server):
    with pytest.raises(NetAppRefused, match="--rtp-ports"):
        with NetAppClient(tiny_server.url, transport="rtp", connect_timeout_s=5) as client:
            client.connect()


def test_rtp_carries_h264_only():
    with pytest.raises(ValueError, match="H.264 only"):
        NetAppClient("http://127.0.0.1:9", transport="rtp", codec="jpeg")
