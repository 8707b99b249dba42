"""One frame type on the robot (`netapp.frame.EncodedFrame`): the encoders make it, the link adds what each netapp
gets (its deadline, the latency report, the trace context) without changing it, and each transport turns it into its
own wire at its edge only, as the wire was before (5G-ERA's Socket.IO dict, HTTP headers, the frames message)."""

from __future__ import annotations

import inspect

import numpy as np

import netapp.client.encoders as encoders
import netapp.client.netapp_client as netapp_client
from netapp.client.link import NetAppLink
from netapp.client.send_settings import SendSettings
from netapp.client.transports import SessionSettings, TransportCallbacks
from netapp.client.transports.http import HttpTransport
from netapp.client.transports.socketio import era_message
from netapp.frame import EncodedFrame
from netapp.frames_session import FramesSession
from netapp.framing import parse_frame

TRACE = {"traceparent": "00-" + "1" * 32 + "-" + "2" * 16 + "-01"}
LATENCY = {"uplink_ms": 1.5, "downlink_ms": 2.0}


def test_the_encoders_make_the_one_frame_type():
    assert not hasattr(encoders, "EncodedFrame") or encoders.EncodedFrame is EncodedFrame  # no second frame type
    picture = np.zeros((32, 48, 3), np.uint8)
    frame = encoders.JpegEncoder().encode(7, picture, SendSettings())
    assert type(frame) is EncodedFrame and (frame.codec, frame.timestamp, frame.width) == ("jpeg", 7, 0)
    assert frame.payload.startswith(b"\xff\xd8") and frame.deadline_ms is None and frame.meta is None
    assert encoders.JpegEncoder().encode(8, b"\xff\xd8jpeg", SendSettings()).payload == b"\xff\xd8jpeg"


def addressed(deadline_ms: float | None) -> tuple[EncodedFrame, EncodedFrame]:
    link = NetAppLink.__new__(NetAppLink)  # only what `_addressed` reads
    link._reported, link._network = LATENCY, [10.0]
    frame = EncodedFrame("jpeg", 7, b"\xff\xd8")
    return frame, link._addressed(frame, deadline_ms, TRACE)


def test_the_link_addresses_a_copy():
    frame, sent = addressed(100.0)
    assert frame.deadline_ms is None and frame.meta is None  # one encoding serves every netapp
    assert sent.deadline_ms == 90.0 and sent.meta == {**TRACE, "latency": LATENCY}


def test_socketio_carries_5g_eras_dict_as_before():
    _, sent = addressed(100.0)
    assert era_message(sent) == {"timestamp": 7, "frame": b"\xff\xd8", "deadline_ms": 90.0, "metadata": sent.meta}
    assert era_message(EncodedFrame("jpeg", 7, b"x")) == {"timestamp": 7, "frame": b"x"}
    h264 = EncodedFrame("h264", 8, b"\x00\x00\x01", 640, 480)
    assert era_message(h264) == {"timestamp": 8, "frame": b"\x00\x00\x01", "width": 640, "height": 480}


def test_http_carries_the_frame_in_its_body_and_headers():
    _, sent = addressed(100.0)
    ignore = lambda *args: None  # noqa: E731
    transport = HttpTransport("http://x", SessionSettings(token="t"), TransportCallbacks(*[ignore] * 7))
    transport._session_id = "s"
    assert transport._headers(sent, "image/jpeg") == {
        "X-Session-Id": "s",
        "X-Timestamp": "7",
        "Content-Type": "image/jpeg",
        "X-Deadline-Ms": "90.0",
        "Authorization": "Bearer t",
        "X-Robot-Latency": '{"uplink_ms":1.5,"downlink_ms":2.0}',
        **TRACE,
    }


def test_frames_carries_it_whole():
    _, sent = addressed(100.0)
    assert parse_frame(FramesSession().frame(sent)) == sent


def test_netapp_client_is_a_facade_of_at_most_300_lines():
    assert len(inspect.getsource(netapp_client).splitlines()) <= 300
