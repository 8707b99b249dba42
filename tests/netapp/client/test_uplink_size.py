"""What the robot sends: no more pixels than the netapp's processor uses (issue 21, item 1), its boxes back in the
robot's own frame, full frames on request, the send settings changed mid-stream (H.264 restarts cleanly)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import requests

from netapp.client import NetAppClient
from netapp.client.send_settings import SendSettings
from netapp.client.sizing import fit_scale, send_size, to_source_coordinates
from netapp.models.matching import box_iou
from tests.support.polling import wait_until
from tests.support.processors import ShapeRecorder
from tests.support.raw_robot import RawRobot

HD = (1280, 720)


def hd_frame(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    frame = np.zeros((HD[1], HD[0], 3), np.uint8)
    frame[:, :, 1] = rng.integers(0, 255, HD[0], np.uint8)  # texture, so H.264 has something to code
    cv2.rectangle(frame, (200 + seed, 100), (600, 500), (255, 255, 255), -1)
    return frame


# -- pure: the size to send and the way back ---------------------------------------------------------------------


def test_the_frame_is_fitted_inside_the_processors_box_like_its_letterbox() -> None:
    assert fit_scale(HD, (416, 416)) == pytest.approx(416 / 1280)  # what YOLOX's letterbox does to the frame
    assert send_size(HD, (416, 416)) == (416, 234)
    assert send_size((720, 1280), (416, 416)) == (234, 416)  # portrait: the long side is the height
    assert send_size(HD, (640, 640), long_side=320) == (320, 180)  # the robot's own cap, when smaller
    assert send_size(HD, (416, 416), full_frames=True) == HD
    assert send_size(HD, (416, 416), long_side=320, full_frames=True) == (320, 180)  # the cap still holds
    assert send_size((320, 240), (416, 416)) == (320, 240)  # never larger than the source
    assert send_size(HD, None) == HD  # a processor that takes any size
    assert send_size((1001, 333), (500, 500)) == (500, 166)  # even sides for H.264 (166.3 -> 166)
    assert all(side % 2 == 0 for side in send_size((1279, 719), (415, 415)))


def test_boxes_go_back_to_the_source_pixels_and_nothing_else_changes() -> None:
    message = {"timestamp": 1, "detections": [{"bbox": [10, 20, 208, 117], "class": 0}, {"no": "bbox"}], "x": [1]}
    back = to_source_coordinates(message, (416, 234), HD)
    assert back["detections"][0]["bbox"] == pytest.approx([10 * 1280 / 416, 20 * 720 / 234, 640, 360], abs=0.1)
    assert back["detections"][1] == {"no": "bbox"} and back["x"] == [1]
    assert message["detections"][0]["bbox"] == [10, 20, 208, 117]  # the netapp's message is not changed
    assert to_source_coordinates(message, HD, HD) is message


def test_send_settings_are_checked() -> None:
    for bad in ({"long_side": 8}, {"jpeg_quality": 0}, {"jpeg_quality": 101}, {"bitrate_kbps": 0}):
        with pytest.raises(ValueError):
            SendSettings(**bad)


# -- a real netapp on loopback ---------------------------------------------------------------------------------------


def test_register_init_and_metadata_say_the_processors_input_size(serve) -> None:
    server = serve(ShapeRecorder((416, 320)))
    answer = requests.post(f"{server.url}/register", json={}, timeout=5).json()
    assert answer["input_size"] == [416, 320]
    assert requests.get(f"{server.url}/v2/models/shapes", timeout=5).json()["input_size"] == [416, 320]
    robot = RawRobot(server.url)
    try:
        assert tuple(robot.init()) == (True, "initialized")  # the 5G-ERA ack is unchanged
        assert robot.next("session_info") == {"input_size": [416, 320], "accuracy_profile": None}
    finally:
        robot.close()
    anything = serve(ShapeRecorder(None))
    assert requests.post(f"{anything.url}/register", json={}, timeout=5).json()["input_size"] is None


def test_the_detectors_size_is_its_models(tiny_detector) -> None:
    tiny_detector.load()
    assert tiny_detector.input_size == (64, 64)
    assert tiny_detector.accuracy_profile is None  # no profile was made for it (tests/netapp/models/test_profiles.py)


def test_a_robot_adapts_only_with_a_profile_for_the_netapps_processor(serve) -> None:
    """A custom processor that names no accuracy profile gets frames as the robot is told (no quality chosen from
    a detector's profile); one that names the shipped one gets an adapting robot."""
    frame = np.full((240, 320, 3), 90, np.uint8)
    for profile, adapts in ((None, False), ("yolox_nano", True)):
        processor = ShapeRecorder((416, 320))
        processor.accuracy_profile = profile
        server = serve(processor)
        answer = requests.post(f"{server.url}/register", json={}, timeout=5).json()
        assert answer["accuracy_profile"] == profile
        with NetAppClient(server.url, transport="ws", adapt="auto") as client:
            client.send(frame)
            assert next(client.results(timeout=10))
            report = client.adapt_report()
        assert (report["off"] is None) == adapts and (report["settings"] is not None) == adapts


@pytest.mark.parametrize("transport", ["ws", "http", "h264", "frames"])
def test_the_robot_sends_no_more_than_the_processor_uses_and_gets_boxes_in_its_own_frame(serve, transport) -> None:
    if transport == "h264":
        pytest.importorskip("av", reason="PyAV is not installed (pip install 'netapp-toolkit[h264]')")
    processor = ShapeRecorder((416, 416))
    server = serve(processor)
    with NetAppClient(server.url, transport=transport, max_in_flight=1) as client:
        assert client.input_sizes == {server.url: (416, 416)}
        results = []
        for i in range(3):
            client.send(hd_frame(i))
            results += wait_until(lambda: list(client.results(timeout=0)), what="a result")
        sent_bytes = client.stats.bytes_sent
    assert set(processor.sizes) == {(416, 234)}
    assert all(r.detections[0]["bbox"] == [0, 0, 1280, 720] for r in results)
    with NetAppClient(server.url, transport=transport, max_in_flight=1, full_frames=True) as client:
        for i in range(3):
            client.send(hd_frame(i))
            wait_until(lambda: list(client.results(timeout=0)), what="a result")
        assert client.stats.bytes_sent > 2 * sent_bytes
    assert processor.sizes[3:] == [HD] * 3


def test_jpeg_bytes_from_the_robot_go_as_they_are(serve) -> None:
    processor = ShapeRecorder((416, 416))
    server = serve(processor)
    data = cv2.imencode(".jpg", hd_frame())[1].tobytes()
    with NetAppClient(server.url, transport="ws") as client:
        client.send(data)
        [result] = wait_until(lambda: list(client.results(timeout=0)), what="a result")
    assert processor.sizes == [HD] and result.detections[0]["bbox"] == [0, 0, 1280, 720]
    assert client.stats.bytes_sent == len(data)


def test_a_size_change_mid_stream_restarts_h264_cleanly_and_each_frame_keeps_its_scale(serve) -> None:
    pytest.importorskip("av", reason="PyAV is not installed (pip install 'netapp-toolkit[h264]')")
    processor = ShapeRecorder((640, 640))
    server = serve(processor)
    results = []
    with NetAppClient(server.url, transport="h264", max_in_flight=2, on_result=results.append) as client:
        for i in range(24):
            if i == 8:
                client.set_send_settings(long_side=320)
            if i == 16:
                client.set_send_settings(SendSettings(long_side=None, jpeg_quality=70))
            client.send(hd_frame(i))
            wait_until(lambda n=i: len(results) + client.stats.dropped_client >= n, what="all but the newest answered")
        assert client.wait_idle(10)
        assert client.stats.errors == 0, client.stats.last_error
        assert client.send_settings == SendSettings(long_side=None, jpeg_quality=70)
    assert {(640, 360), (320, 180)} <= set(processor.sizes)
    assert processor.sizes[-1] == (640, 360)  # back up once the cap went: a new stream again
    assert len(results) >= 20 and all(r.detections[0]["bbox"] == [0, 0, 1280, 720] for r in results)


def test_boxes_of_the_downscaled_frame_land_where_the_full_frames_do(serve, real_model_path, media_dir) -> None:
    from netapp.models import Detector, DetectorConfig

    image = cv2.imread(str(media_dir / "dog.jpg"))
    large = cv2.resize(image, HD, interpolation=cv2.INTER_CUBIC)  # a 1280x720 robot camera's frame
    server = serve(Detector(DetectorConfig(str(real_model_path))))
    boxes = {}
    for full in (False, True):
        with NetAppClient(server.url, transport="ws", full_frames=full) as client:
            client.send(large)
            [result] = wait_until(lambda c=client: list(c.results(timeout=0)), what="a result")
            boxes[full] = result.detections
            assert client.stats.sent_size == ((416, 234) if not full else HD)
    assert len(boxes[True]) >= 2  # dog, bicycle, truck
    for reference in boxes[True]:
        best = max(box_iou(reference["bbox"], d["bbox"]) for d in boxes[False] if d["class"] == reference["class"])
        assert best >= 0.8, (reference, boxes[False])
