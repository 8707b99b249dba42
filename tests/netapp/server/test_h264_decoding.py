"""The H.264 path's parts without a network: the client's encoder, the netapp's stream decoder (its order, its
bounds, its refusals), and, in a netapp in process, a stream's decoder released when idle and held to its budget.
A real server and the era-5g-client: test_h264.py."""

from __future__ import annotations

import asyncio
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import pytest

av = pytest.importorskip("av")

from netapp.client.h264 import H264Encoder, encode_frame  # noqa: E402
from netapp.client.netapp_client import NetAppClient  # noqa: E402
from netapp.client.transports.socketio import era_message  # noqa: E402
from netapp.frame import H264, EncodedFrame  # noqa: E402
from netapp.protocol import H264_EVENT  # noqa: E402
from netapp.server.decoding.h264 import H264Decoder, StreamDecoder  # noqa: E402
from netapp.server.decoding.h264_bitstream import FrameNumTracker, contains_idr  # noqa: E402
from netapp.server.errors import FrameRejected  # noqa: E402
from netapp.server.settings import Settings  # noqa: E402
from netapp.server.sio.messages import frame_from_message  # noqa: E402
from tests.netapp.server.test_socketio import RawRobot  # noqa: E402
from tests.support.h264_colours import (  # noqa: E402
    DEADLINE_S,
    HEIGHT,
    PALETTE,
    TOLERANCE,
    WIDTH,
    assert_colour,
    colour_frame,
    stream_messages,
)


def as_frame(message: dict[str, Any]) -> EncodedFrame:
    """A 5G-ERA H.264 message as Socket.IO's edge hands it to the decoder."""
    return frame_from_message(message, H264, 1 << 30)


# -- the client encoder and the ordering mechanism, without a server ----------------------------------------------


def test_encoder_starts_with_a_keyframe_and_honours_the_interval() -> None:
    encoder = H264Encoder(WIDTH, HEIGHT)
    keys = [i for i in range(60) if encoder.encode(colour_frame(i))[1]]
    assert keys == [0, 25, 50]
    encoder = H264Encoder(WIDTH, HEIGHT, {"g": "10"})
    flags = [encoder.encode(colour_frame(i)) for i in range(30)]
    assert [i for i, (data, key) in enumerate(flags) if key] == [0, 10, 20]
    assert all(data for data, _ in flags), "zero latency: every frame gives its packet at once"
    assert [i for i, (data, _) in enumerate(flags) if contains_idr(data)] == [0, 10, 20]


def test_encode_frame_message_and_new_encoder_on_size_change() -> None:
    frame, encoder = encode_frame(None, colour_frame(0), 7)
    assert (frame.codec, frame.timestamp, frame.width, frame.height) == ("h264", 7, WIDTH, HEIGHT)
    assert era_message(frame) == {"timestamp": 7, "frame": frame.payload, "width": WIDTH, "height": HEIGHT}
    frame, same = encode_frame(encoder, colour_frame(1), 8)
    assert same is encoder and not contains_idr(frame.payload)
    frame, other = encode_frame(encoder, colour_frame(2, 64, 48), 9)
    assert other is not encoder and contains_idr(frame.payload) and (frame.width, frame.height) == (64, 48)
    with pytest.raises(ValueError, match="even"):
        encode_frame(None, colour_frame(0, 63, 48), 1)


def test_a_stream_decodes_in_order_whichever_frames_run() -> None:
    """Frames the pipeline dropped are never decoded alone: the next frame that runs decodes their packets first,
    in arrival order, on whichever thread runs it, so every picture comes out right; a frame whose packet a later
    one already went past is refused, never answered with another frame's picture."""

    async def queue(stream: Any, messages: list[dict[str, Any]]) -> list[Any]:
        return [stream.frame(as_frame(m)) for m in messages]  # on the loop, in arrival order, as the transport does

    stream = H264Decoder().open()
    decodings = asyncio.run(queue(stream, stream_messages(60)))
    runs = [i for i in range(60) if i % 3 == 2]  # the others were superseded (newest wins)
    with ThreadPoolExecutor(2) as pool:  # two lanes, taking turns
        for i in runs:
            picture = pool.submit(decodings[i]).result(timeout=DEADLINE_S)
            colour = picture.reshape(-1, 3).mean(axis=0)
            assert np.abs(colour - PALETTE[i % len(PALETTE)]).max() <= TOLERANCE, f"frame {i}: decoded {colour}"
    assert stream.decoder.resets == 0
    with pytest.raises(FrameRejected) as refused:
        decodings[30]()  # its packet was decoded on frame 32's turn
    assert refused.value.reason == "h264_overloaded"
    stream.close()
    assert not stream.decoder.is_open


def test_packets_waiting_for_a_turn_are_bounded_by_their_decoding_time(monkeypatch) -> None:
    """Packets wait for their frame's turn on a lane, which decodes them all: past MAX_PENDING_DECODE_S of
    decoding (estimated from what the stream's packets cost so far) the stream skips to its next keyframe, so a
    flood never holds a lane for long, whatever the count and bytes bounds would still allow."""
    from netapp.server.decoding import h264

    monkeypatch.setattr(h264, "MAX_PENDING_DECODE_S", 0.01)
    encoder, rng = H264Encoder(320, 240, {"g": "1"}), np.random.default_rng(0)  # noise: keyframes of real weight
    keyframes = [
        {"timestamp": i + 1, "frame": encoder.encode(rng.integers(0, 255, (240, 320, 3), np.uint8))[0]}
        | {"width": 320, "height": 240}
        for i in range(40)
    ]

    async def flood(stream: Any) -> tuple[int, FrameRejected]:
        stream.frame(as_frame(keyframes[0]))()  # decoded: what a packet costs is known from here
        for i, message in enumerate(keyframes[1:], 1):
            try:
                stream.frame(as_frame(message))
            except FrameRejected as exc:
                return i, exc
        raise AssertionError("the flood was never refused")

    stream = H264Decoder().open()
    refused_at, refused = asyncio.run(flood(stream))
    assert refused.reason == "h264_overloaded" and "of decoding" in str(refused)
    assert refused_at < len(keyframes) - 1 < h264.MAX_BACKLOG
    assert sum(len(m["frame"]) for m in keyframes[:refused_at]) < h264.MAX_BACKLOG_BYTES
    assert stream.backlog()[0] == 0  # the waiting packets were dropped with it


def test_refused_packets_leave_one_reset_and_never_make_the_stream_look_behind() -> None:
    """A stream whose first keyframe never came whole (an RTP stream's SPS lost) has its packets refused until a
    keyframe with its size: each refusal's reset waits for the next decoding, once, however many there were, and
    however long ago (a reset is no packet waiting: it once refused every packet after MAX_LAG_S, for good)."""
    from netapp.server.decoding import h264

    messages = stream_messages(26)  # a keyframe at 0 and at 25 (the encoder's interval)

    async def refused_then_keyframe(stream: Any) -> Any:
        for message in messages[1:25]:  # P-frames without a size, and no decoder open
            with pytest.raises(FrameRejected, match="width"):
                stream.frame(as_frame({k: v for k, v in message.items() if k not in ("width", "height")}))
        assert len(stream._jobs._jobs) == 1 and stream.backlog() == (0, 0.0, 0)  # one reset waits, no packet
        for job in stream._jobs._jobs:
            job.queued_at -= 2 * h264.MAX_LAG_S  # it has waited that long
        return stream.frame(as_frame(messages[25]))

    stream = H264Decoder().open()
    decoding = asyncio.run(refused_then_keyframe(stream))
    picture = decoding()
    assert np.abs(picture.reshape(-1, 3).mean(axis=0) - PALETTE[25 % len(PALETTE)]).max() <= TOLERANCE
    stream.close()


@pytest.mark.parametrize(
    "options",
    [
        None,  # ours: ultrafast, zerolatency (Constrained Baseline)
        {
            "preset": "medium",
            "tune": "zerolatency",
            "x264-params": "cqm=jvt",
        },  # High profile, scaling matrices in the SPS
    ],
)
def test_frame_num_tracker_spots_a_missing_reference_picture(options) -> None:
    packets = [m["frame"] for m in stream_messages(30, options, 160, 120)]
    tracker = FrameNumTracker()
    assert all(tracker.follows(p) for p in packets)
    tracker = FrameNumTracker()
    assert [i for i, p in enumerate(packets) if i != 7 and not tracker.follows(p)] == [8]


def test_decoder_refuses_pictures_after_a_lost_packet_until_the_keyframe() -> None:
    """FFmpeg would conceal the gap and return damaged pictures; the decoder resets and waits for the keyframe."""
    decoder, outcomes = StreamDecoder(), {}
    for i, message in enumerate(stream_messages(30)):
        if i == 10:
            continue  # dropped after encoding, as era-5g-client does under back-pressure
        try:
            picture = decoder.decode(message["frame"], WIDTH, HEIGHT)
            assert_colour({"colour": picture.reshape(-1, 3).mean(axis=0)}, i)
            outcomes[i] = "ok"
        except FrameRejected as exc:
            outcomes[i] = exc.reason
    assert outcomes[9] == "ok" and outcomes[11] == "h264_missing_packet"
    assert {outcomes[i] for i in range(12, 25)} == {"h264_waiting_keyframe"}
    assert {outcomes[i] for i in range(25, 30)} == {"ok"}
    assert decoder.resets == 1


def test_without_pyav_the_event_answers_why(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "av", None)  # makes `import av` raise ImportError
    decoder = H264Decoder()
    with pytest.raises(FrameRejected, match="PyAV is not installed"):
        decoder.open().frame(as_frame({"timestamp": 1, "frame": b"\x00", "width": 2, "height": 2}))
    from netapp.client.h264 import require_av

    with pytest.raises(ImportError, match=r"netapp-toolkit\[h264\]"):
        require_av()
    with pytest.raises(ImportError, match="PyAV"):
        NetAppClient("http://127.0.0.1:1", transport="h264")


# -- a stream in a netapp in process: its decoder released when idle, its decoding held to its budget ----------


def test_an_idle_h264_stream_holds_no_decoder(serve, tiny_detector, monkeypatch) -> None:
    pytest.importorskip("av")
    from netapp.client.h264 import H264Encoder
    from netapp.server.decoding import h264

    monkeypatch.setattr(h264, "IDLE_RELEASE_S", 0.3)
    server = serve(tiny_detector)
    robot = RawRobot(server.url)
    try:
        assert robot.init()[0]
        encoder = H264Encoder(64, 64)
        frame = np.zeros((64, 64, 3), np.uint8)
        robot.frame({"timestamp": 1, "frame": encoder.encode(frame)[0], "width": 64, "height": 64}, event=H264_EVENT)
        assert robot.next("results")["timestamp"] == 1
        [connection] = server.app.other_asgi_app.state.dataplane.connections("ws")
        stream = connection.decoders[H264_EVENT]
        assert stream.decoder.is_open
        deadline = time.monotonic() + 10
        while stream.decoder.is_open:  # polled with a deadline: closed once idle
            assert time.monotonic() < deadline
            time.sleep(0.05)
        robot.frame({"timestamp": 2, "frame": encoder.encode(frame)[0], "width": 64, "height": 64}, event=H264_EVENT)
        assert robot.next("data_error")["reason"] == "h264_waiting_keyframe"  # resumes at the next keyframe
    finally:
        robot.close()


def test_an_h264_stream_over_its_decode_budget_skips_to_its_next_keyframe(serve, tiny_detector, monkeypatch) -> None:
    pytest.importorskip("av")
    from netapp.client.h264 import H264Encoder
    from netapp.server.decoding import h264

    monkeypatch.setattr(h264, "DECODE_BURST_S", 0.01)
    server = serve(tiny_detector, Settings(h264_decode_share=0.01))
    encoder = H264Encoder(640, 360, {"g": "1"})
    rng = np.random.default_rng(1)
    keyframes = [encoder.encode(rng.integers(0, 255, (360, 640, 3), np.uint8))[0] for _ in range(12)]
    robot = RawRobot(server.url)
    try:
        assert robot.init()[0]
        replies = []
        for i, packets in enumerate(keyframes):  # one at a time: each decode is charged before the next packet
            robot.frame({"timestamp": i, "frame": packets, "width": 640, "height": 360}, event=H264_EVENT)
            replies.append(robot.next_of("results", "data_error"))
        assert replies[0][0] == "results"  # within its budget at first
        errors = [data for event, data in replies if event == "data_error"]
        assert errors and all(e["reason"] == "h264_overloaded" and "decoding budget" in e["error"] for e in errors)
    finally:
        robot.close()
