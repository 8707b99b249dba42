"""`netapp stream --source BAG --mcap OUT`: ROS 2 bags (MCAP, sqlite3) and ROS 1 bags of Image and CompressedImage
stream through a real netapp; every result and every message of the output carries its image's header stamp, and
the output decodes with mcap-ros2-support and rosbags."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("rosbags")
pytest.importorskip("mcap_ros2")

from netapp.cli import main as netapp_main  # noqa: E402
from tests.support.bags import PERIOD_NS, grey_frames, read_mcap, stamp_ns, write_bag  # noqa: E402

TINY_BOX = [20, 40, 100, 120]  # where the tiny model finds its box in a grey 160x160 frame


def run_stream(capsys, url: str, source: Path, *extra: str) -> dict:
    code = netapp_main(["stream", url, "--source", str(source), "--transport", "http", "--json", *extra])
    out = capsys.readouterr()
    assert code == 0, out.err
    return json.loads(out.out)


@pytest.mark.parametrize(
    "storage,compressed,encoding",
    [("mcap", "", "rgb8"), ("sqlite3", "jpeg", "bgr8"), ("ros1", "", "mono8"), ("mcap", "png", "bgr8")],
)
def test_a_bag_streams_and_every_output_carries_its_images_stamp(
    tmp_path, capsys, tiny_server, storage, compressed, encoding
):
    bag = tmp_path / ("run.bag" if storage == "ros1" else "run")
    stamps = write_bag(bag, grey_frames(6), storage, encoding=encoding, compressed=compressed)
    lines, out = tmp_path / "results.jsonl", tmp_path / "out.mcap"
    summary = run_stream(capsys, tiny_server.url, bag, "--rate", "0", "--jsonl", str(lines), "--mcap", str(out))

    assert summary["recording"] == {"topic": "/camera/image", "frames": 6, "skipped": {}}
    records = [json.loads(line) for line in lines.read_text().splitlines()]
    assert [r["source_stamp_ns"] for r in records] == stamps  # --rate 0: each frame answered before the next
    assert records[0]["detections"][0]["bbox"] == pytest.approx(TINY_BOX, abs=1)

    topics = read_mcap(out)
    assert set(topics) == {"/netapp/image", "/netapp/detections", "/netapp/annotations", "/netapp/latency"}
    for topic, messages in topics.items():
        assert [t for t, _ in messages] == stamps, topic
    for (log_time, image), (_, array) in zip(topics["/netapp/image"], topics["/netapp/detections"], strict=True):
        assert stamp_ns(image.header.stamp) == stamp_ns(array.header.stamp) == log_time
        assert image.format == (compressed or "jpeg") and image.header.frame_id == "camera"
        detection = array.detections[0]
        assert stamp_ns(detection.header.stamp) == log_time
        assert detection.results[0].hypothesis.class_id == "robot"  # the tiny model's class, by name
        assert detection.results[0].hypothesis.score > 0.5
        box = detection.bbox
        assert (box.center.position.x, box.center.position.y, box.size_x, box.size_y) == pytest.approx(
            (60, 80, 80, 80), abs=1
        )
    for log_time, overlay in topics["/netapp/annotations"]:
        box = overlay.points[0]
        assert stamp_ns(box.timestamp) == stamp_ns(overlay.texts[0].timestamp) == log_time
        corners = [v for p in box.points for v in (p.x, p.y)]
        assert corners == pytest.approx([20, 40, 100, 40, 100, 120, 20, 120], abs=1)
        assert overlay.texts[0].text.startswith("robot 0.")
    for log_time, latency in topics["/netapp/latency"]:
        assert stamp_ns(latency.header.stamp) == log_time
        assert 0 < latency.inference_ms <= latency.latency_ms


def test_recorded_jpeg_bytes_go_into_the_mcap_as_they_are(tmp_path, capsys, tiny_server):
    from rosbags.highlevel import AnyReader

    bag = tmp_path / "run"
    write_bag(bag, grey_frames(3), "mcap", compressed="jpeg")
    with AnyReader([bag]) as reader:
        recorded = [bytes(reader.deserialize(raw, c.msgtype).data) for c, _, raw in reader.messages()]
    out = tmp_path / "out.mcap"
    run_stream(capsys, tiny_server.url, bag, "--rate", "0", "--mcap", str(out))
    assert [bytes(m.data) for _, m in read_mcap(out)["/netapp/image"]] == recorded


def test_the_output_reads_with_rosbags_and_the_ros2_definitions(tmp_path, capsys, tiny_server):
    from rosbags.highlevel import AnyReader

    bag = tmp_path / "run"
    stamps = write_bag(bag, grey_frames(4), "mcap")
    out = tmp_path / "out.mcap"
    run_stream(capsys, tiny_server.url, bag, "--rate", "0", "--mcap", str(out))
    with AnyReader([out]) as reader:
        connections = [c for c in reader.connections if c.topic == "/netapp/detections"]
        assert connections[0].msgtype == "vision_msgs/msg/Detection2DArray"
        arrays = [(t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages(connections=connections)]
    assert [stamp_ns(a.header.stamp) for _, a in arrays] == [t for t, _ in arrays] == stamps
    assert all(a.detections[0].results[0].hypothesis.class_id == "robot" for _, a in arrays)


@pytest.mark.parametrize("rate", [1.0, 2.0])
def test_a_bag_replays_at_its_recorded_rate_times_rate(tmp_path, capsys, tiny_server, rate):
    bag = tmp_path / "run"
    count = 11
    write_bag(bag, grey_frames(count), "mcap")
    summary = run_stream(capsys, tiny_server.url, bag, "--rate", str(rate))
    recorded_s = (count - 1) * PERIOD_NS / 1e9
    assert summary["duration_s"] == pytest.approx(recorded_s / rate, rel=0.2, abs=0.06)
    assert summary["results"] == count and summary["recording"]["frames"] == count


def test_a_recorded_jpeg_is_fitted_to_the_netapps_input_unless_full_frames(tmp_path, capsys, tiny_server):
    """A bag's JPEG goes like any frame: fitted to what the model uses, as recorded only with --full-frames."""
    bag = tmp_path / "run"
    write_bag(bag, grey_frames(3, width=320, height=240), "mcap", compressed="jpeg")
    fitted = run_stream(capsys, tiny_server.url, bag, "--rate", "0")
    whole = run_stream(capsys, tiny_server.url, bag, "--rate", "0", "--full-frames")
    assert fitted["results"] == whole["results"] == 3
    width, _ = (int(side) for side in fitted["sent_size"].split("x"))
    assert width < 320 and whole["sent_size"] is None  # the recorded bytes, not encoded here
    assert fitted["bytes_per_frame"] < whole["bytes_per_frame"]
