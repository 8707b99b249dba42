"""The `frames` transport's netapp side: the wire format (`netapp.framing`) on a real uvicorn netapp, raw robots
sending good and hostile messages, tokens, draining, deadlines."""

from __future__ import annotations

import asyncio
import json
import socket

import numpy as np
import pytest
import requests
from websockets.client import ClientProtocol
from websockets.protocol import State
from websockets.uri import parse_uri

from netapp.client import NetAppClient
from netapp.client.transports.frames import frames_url
from netapp.frame import EncodedFrame
from netapp.framing import HEADER, KIND_FRAME, MAX_META_BYTES, WireError, pack_frame, parse_frame
from netapp.server.access import token_digest
from netapp.server.frames.connection import LOW_WATER, MAX_UNSENT, FramesWire
from netapp.server.settings import Settings
from tests.support.images import make_jpeg
from tests.support.onnx_models import TINY_NAMES
from tests.support.polling import wait_until
from tests.support.processors import LargeResults
from tests.support.raw_frames_robot import RawFramesRobot


def metric(url: str, line: str) -> float:
    for row in requests.get(f"{url}/metrics", timeout=5).text.splitlines():
        if row.startswith(line + " "):
            return float(row.split()[-1])
    return 0.0


@pytest.fixture
def robots():
    started: list[RawFramesRobot] = []

    def connect(url: str, **options) -> RawFramesRobot:
        started.append(RawFramesRobot(url, **options))
        return started[-1]

    yield connect
    for robot in started:
        robot.close()


# -- the format on its own ------------------------------------------------------------------------------------------


def test_a_frame_message_is_read_back_as_it_was_written():
    data = pack_frame(
        EncodedFrame("h264", 2**62, b"\x00\x01", width=640, height=480, deadline_ms=150.5, meta={"latency": {"a": 1}})
    )
    frame = parse_frame(data)
    assert (frame.codec, frame.timestamp, frame.payload, frame.width, frame.height) == (
        "h264",
        2**62,
        b"\x00\x01",
        640,
        480,
    )
    assert frame.deadline_ms == 150.5 and frame.meta == {"latency": {"a": 1}}
    bare = parse_frame(pack_frame(EncodedFrame("jpeg", 7, b"x")))
    assert (bare.deadline_ms, bare.meta, len(pack_frame(EncodedFrame("jpeg", 7, b"")))) == (None, None, HEADER.size)


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"\x01\x01\x00", "truncated"),
        (HEADER.pack(9, 1, 0, 0, 0, 0.0, 1), "unknown_kind"),
        (HEADER.pack(KIND_FRAME, 7, 0, 0, 0, 0.0, 1), "bad_codec"),
        (HEADER.pack(KIND_FRAME, 1, 50, 0, 0, 0.0, 1) + b"{}", "bad_meta"),  # longer than the message
        (HEADER.pack(KIND_FRAME, 1, MAX_META_BYTES + 1, 0, 0, 0.0, 1) + b" " * 5000, "bad_meta"),
        (HEADER.pack(KIND_FRAME, 1, 3, 0, 0, 0.0, 1) + b"{x]", "bad_meta"),
        (HEADER.pack(KIND_FRAME, 1, 2, 0, 0, 0.0, 1) + b"[]", "bad_meta"),
        (HEADER.pack(KIND_FRAME, 1, 0, 0, 0, float("nan"), 1), "bad_deadline"),
        (HEADER.pack(KIND_FRAME, 1, 0, 0, 0, -5.0, 1), "bad_deadline"),
    ],
)
def test_a_malformed_frame_message_says_what_is_wrong(data: bytes, reason: str):
    with pytest.raises(WireError) as error:
        parse_frame(data)
    assert error.value.reason == reason


# -- a real netapp ----------------------------------------------------------------------------------------------------


def test_init_tells_the_session_then_frames_get_results(tiny_server, robots):
    robot = robots(tiny_server.url)
    ack = robot.init(robot_id="r1")
    assert ack["ok"] is True and ack["message"] == "initialized" and ack["session_id"]
    assert robot.order == ["session_info", "ack"]  # what the robot needs before its first frame, before the ack
    robot.frame(42, meta={"latency": {"uplink_ms": 3.0, "downlink_ms": 2.0}}, deadline_ms=5000)
    result = robot.next("results")
    assert result["timestamp"] == 42 and result["detections"][0]["class_name"] == TINY_NAMES[2]
    assert {"recv_timestamp", "timestamp_before_process", "timestamp_after_process", "send_timestamp"} <= result.keys()
    (view,) = tiny_server.app.other_asgi_app.state.live.robots()
    assert view.reported == (3.0, 2.0)  # the robot's latency report reached the live pages
    assert robot.command(3)["ok"] is True  # GET_STATE of a stateless netapp: its counters
    assert robot.init()["ok"] is False  # a second INIT


def test_every_bad_message_gets_one_error_is_counted_and_the_connection_goes_on(tiny_server, robots):
    url = tiny_server.url
    robot = robots(url)
    robot.frame(1)
    assert robot.next("error")["reason"] == "no_session"
    robot.init()
    bad = {
        "truncated": b"\x01\x01",
        "unknown_kind": HEADER.pack(9, 1, 0, 0, 0, 0.0, 2) + make_jpeg(),
        "bad_codec": HEADER.pack(KIND_FRAME, 9, 0, 0, 0, 0.0, 3) + make_jpeg(),
        "bad_meta": HEADER.pack(KIND_FRAME, 1, 4, 0, 0, 0.0, 4) + b"\xff{]x" + make_jpeg(),
        "bad_frame": pack_frame(EncodedFrame("jpeg", 5, b"not a jpeg")),
    }
    for reason, data in bad.items():
        robot.send(data)
        error = robot.next("error")
        assert error["reason"] == reason and error["error"], error
    robot.send("{not json")
    assert robot.next("error")["reason"] == "malformed"
    robot.send(json.dumps([1, 2]))
    assert robot.next("error")["reason"] == "malformed"
    assert robot.command(99)["ok"] is False  # an unknown command: refused in its ack
    robot.frame(6)
    assert robot.next("results")["timestamp"] == 6  # the connection went on
    for reason, transport in [("truncated", "frames"), ("bad_codec", "frames"), ("bad_frame", "frames")]:
        assert metric(url, f'netapp_frames_rejected_total{{reason="{reason}",transport="{transport}"}}') == 1
    assert metric(url, 'netapp_frames_rejected_total{reason="malformed",transport="frames"}') == 2


def test_a_message_over_the_limits_is_refused_before_it_is_read_and_others_go_on(serve, tiny_detector, robots):
    settings = Settings(lanes=1, max_payload_bytes=100_000)  # a message may be 2x that + 64 KiB
    server = serve(tiny_detector, settings)
    robot, other = robots(server.url), robots(server.url)
    robot.init(), other.init()
    robot.frame(1, payload=make_jpeg() + b"\x00" * 150_000)  # over the frame limit, within the message limit
    assert robot.next("error")["reason"] == "payload_too_large"
    robot.frame(2, payload=b"\xff\xd8\xff" + b"\x00" * (settings.transport_limit_bytes + 1))
    assert robot.closed.wait(10) and robot.close_code == 1009  # closed by uvicorn, the message never buffered
    other.frame(3)
    assert other.next("results")["timestamp"] == 3
    wait_until(lambda: metric(server.url, 'netapp_active_sessions{transport="frames"}') == 1, what="its session closed")


def test_a_token_is_needed_where_the_netapp_has_one(serve, tiny_detector, robots):
    server = serve(tiny_detector, Settings(lanes=1, token_sha256=token_digest("right")))
    for headers in (None, {"Authorization": "Bearer wrong"}):
        refused = robots(server.url, headers=headers)
        assert refused.next("refused")["reason"] == "unauthorized"
        assert refused.closed.wait(10) and (refused.close_code, refused.close_reason) == (1008, "unauthorized")
    for options in ({"headers": {"Authorization": "Bearer right"}}, {"query": "?token=right"}):
        robot = robots(server.url, **options)
        assert robot.init()["ok"] is True


def test_a_draining_netapp_moves_its_robots_and_takes_no_new_ones(serve, tiny_detector, robots):
    server = serve(tiny_detector, Settings(lanes=1, drain_grace_s=30.0))
    robot = robots(server.url)
    robot.init()
    drained = server.call(server.app.drain())
    assert robot.next("move")["reason"] == "draining"
    late = robots(server.url)
    refusal = late.next("refused")
    assert (refusal["reason"], refusal["retry_after_s"]) == ("draining", 1) and "draining" in refusal["error"]
    assert late.closed.wait(10) and late.close_code == 1013
    assert not drained.done(), "its robot is still connected"
    robot.close()
    drained.result(timeout=10)


def test_a_frame_past_its_deadline_is_dropped_and_a_superseded_one_said_so(serve, gated, robots):
    server = serve(gated)
    robot = robots(server.url)
    robot.init()
    robot.frame(1)
    assert gated.entered.acquire(timeout=10)  # frame 1 holds the one lane
    robot.frame(2)
    robot.frame(3, deadline_ms=1)  # supersedes 2 in the queue (newest wins), and cannot make its deadline
    superseded = robot.next("error")
    assert (superseded["timestamp"], superseded["reason"]) == (2, "superseded")
    gated.gate.set()
    late = robot.next("error")
    assert (late["timestamp"], late["reason"]) == (3, "deadline")
    assert metric(server.url, 'netapp_frames_deadline_dropped_total{transport="frames"}') == 1


def test_h264_goes_over_frames_too(tiny_server):
    pytest.importorskip("av", reason="PyAV is not installed (pip install 'netapp-toolkit[h264]')")
    frame = np.zeros((96, 128, 3), np.uint8)
    frame[20:70, 30:90] = 255
    with NetAppClient(tiny_server.url, transport="frames", codec="h264", max_in_flight=1) as client:
        for _ in range(3):
            client.send(frame)
            assert client.wait_idle(20)
        results = list(client.results(timeout=0.5))
        assert len(results) == 3 and client.stats.errors == 0, client.stats
    assert metric(tiny_server.url, 'netapp_frames_processed_total{transport="frames-h264"}') == 3


def silent_robot(url: str) -> tuple[socket.socket, ClientProtocol]:
    """A frames robot that reads nothing after its handshake, with a receive window of a few KB: what it is sent
    stays on the netapp's side."""
    uri = parse_uri(frames_url(url))
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # before connecting: the window it offers
    sock.connect((uri.host, uri.port))
    protocol = ClientProtocol(uri, max_size=None)
    protocol.send_request(protocol.connect())
    sock.sendall(b"".join(protocol.data_to_send()))
    while protocol.state is not State.OPEN:  # the 101 answer; nothing is read after it
        data = sock.recv(4096)
        assert data, "the netapp closed the connection during the handshake"
        protocol.receive_data(data)
    return sock, protocol


def test_a_robot_that_reads_nothing_holds_up_nobody_else(serve, robots):
    """Results go out by each connection's writer task: one robot whose socket takes nothing more never stalls the
    pipeline's delivery for the others, and what waits for it is bounded."""
    server = serve(LargeResults(1_000_000))  # 1 MB results: a few fill the socket buffers between (4 MB at most)
    good = robots(server.url)
    good.init()
    sock, protocol = silent_robot(server.url)
    try:
        protocol.send_text(json.dumps({"id": 1, "cmd_type": 1, "data": {}}).encode())
        jpeg = make_jpeg()
        endpoint = server.app.other_asgi_app.state.frames
        wires = lambda: [c.wire for c in endpoint.connections]  # noqa: E731
        piled_up = lambda: any(len(w.unsent) >= LOW_WATER for w in wires())  # noqa: E731
        for i in range(2000):
            protocol.send_binary(pack_frame(EncodedFrame("jpeg", i, jpeg)))
            sock.sendall(b"".join(protocol.data_to_send()))
            if piled_up():  # its socket takes nothing more: the netapp now reads nothing more from it either
                break
        wait_until(piled_up, what="its messages to pile up")
        assert max(len(w.unsent) for w in wires()) <= MAX_UNSENT
        for i in range(3):
            good.frame(10_000 + i)
            assert good.next("results")["timestamp"] == 10_000 + i  # the pipeline goes on for the others
    finally:
        sock.close()


def test_what_waits_for_a_robot_is_bounded_and_what_is_dropped_counted():
    """A connection whose socket takes nothing keeps MAX_UNSENT messages; each one past it is counted as dropped."""
    dropped = []

    async def main() -> None:
        async def stuck(message: dict) -> None:
            await asyncio.Event().wait()  # a robot that reads nothing: the send never returns

        connection = FramesWire(stuck, dropped=lambda: dropped.append(1))
        for i in range(MAX_UNSENT + 6):
            connection.tell(f"message {i}")
        assert len(connection.unsent) == MAX_UNSENT and len(dropped) == 6
        connection.start()
        connection.stop()

    asyncio.run(main())
