"""`netapp ros2`: a camera process publishes ROS 2 Images over DDS, the bridge process sends them to a real netapp
and publishes Detection2DArray, and this process subscribes with ROS 2's names: every array carries the header
stamp of a published image and the tiny model's box."""

from __future__ import annotations

import json
import sys
import time

import pytest

pytest.importorskip("cyclonedds")

from netapp.ros.bridge import DETECTIONS_DEPTH, dds_topic  # noqa: E402
from tests.support.bags import PERIOD_NS, START_NS  # noqa: E402
from tests.support.bridge_run import run_bridge  # noqa: E402

COUNT = 120  # 6 s of camera at 20 Hz: discovery takes a moment, the rest is answered


def test_the_bridge_publishes_detections_stamped_like_their_images(profiled_tiny_server):
    tiny_server = profiled_tiny_server
    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from netapp.ros.dds_types import Detection2DArray_

    participant = DomainParticipant(0)
    qos = Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(DETECTIONS_DEPTH))
    reader = DataReader(participant, Topic(participant, dds_topic("/netapp/detections"), Detection2DArray_), qos=qos)
    arrays, out, returncode = run_bridge(
        tiny_server.url, reader, "/camera/image", 20, COUNT, "--transport", "http", "--json"
    )
    stamps = {START_NS + i * PERIOD_NS for i in range(COUNT)}
    assert len(arrays) >= 20
    for array in arrays:
        stamp = array.header.stamp.sec * 10**9 + array.header.stamp.nanosec
        assert stamp in stamps and array.header.frame_id == "camera"
        (detection,) = array.detections
        assert detection.results[0].hypothesis.class_id == "robot"
        box = detection.bbox
        assert (box.center.position.x, box.center.position.y, box.size_x, box.size_y) == pytest.approx(
            (60, 80, 80, 80), abs=1
        )
    summary = json.loads(out)
    assert summary["published"] >= len(arrays) and summary["sent"] <= summary["received"]
    assert summary["adapt"]["settings"] is not None  # the uplink adapts by default, as `netapp stream`'s does
    assert returncode == 0


def test_without_cyclonedds_the_bridge_is_one_line(tiny_server, monkeypatch, capsys):
    from netapp.cli import main as netapp_main

    monkeypatch.setitem(sys.modules, "cyclonedds", None)
    code = netapp_main(["ros2", tiny_server.url, "--image-topic", "/camera/image", "--transport", "http"])
    assert code == 1
    assert (
        capsys.readouterr()
        .err.strip()
        .endswith("error: netapp ros2 needs the cyclonedds package: pip install 'netapp-toolkit[ros]'")
    )


def test_the_bridge_sends_like_netapp_stream(tiny_server, capsys):
    """`netapp ros2` takes `netapp stream`'s sending options (--adapt, --budget-ms, --accuracy-floor, --full-frames)
    from the same definition, and its client adapts to them."""
    from netapp.cli import build_parser
    from netapp.cli import main as netapp_main

    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices  # argparse keeps its subcommands here

    def sending(name: str) -> dict[str, tuple]:
        return {
            a.dest: (a.option_strings, a.default, a.choices, a.help)
            for a in commands[name]._actions
            if a.dest in ("adapt", "budget_ms", "accuracy_floor", "full_frames")
        }

    assert len(sending("ros2")) == 4 and sending("ros2") == sending("stream")
    base = ["ros2", tiny_server.url, "--image-topic", "/nobody/camera", "--transport", "http", "--duration", "0.1"]
    netapp_main([*base, "--budget-ms", "120", "--accuracy-floor", "0.9", "--json"])
    adapt = json.loads(capsys.readouterr().out)["adapt"]
    assert (adapt["latency_budget_ms"], adapt["accuracy_floor"]) == (120, 0.9)
    netapp_main([*base, "--adapt", "off", "--full-frames", "--json"])
    assert "adapt" not in json.loads(capsys.readouterr().out)


def test_a_camera_that_goes_away_is_no_image(tiny_server, monkeypatch):
    """A writer's dispose reaches the bridge as a sample without data: skipped, and the next image still goes."""
    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    from netapp.client.netapp_client import NetAppClient
    from netapp.ros.bridge import Ros2Bridge
    from netapp.ros.dds_types import Header_, Image_, Time_

    unraisable = []
    monkeypatch.setattr(sys, "unraisablehook", unraisable.append)  # where an exception in a DDS listener goes
    participant = DomainParticipant(42)
    qos = Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(5))
    writer = DataWriter(participant, Topic(participant, dds_topic("/gone/image"), Image_), qos=qos)
    image = Image_(Header_(Time_(1, 0), "camera"), 160, 160, "bgr8", 0, 480, bytes([90]) * (160 * 160 * 3))
    with NetAppClient(tiny_server.url, transport="http") as client, Ros2Bridge(client, "/gone/image", domain=42) as b:
        for step in ("write", "dispose", "write"):
            published = b.counts["published"]
            deadline = time.monotonic() + 10
            while b.counts["published"] == published and time.monotonic() < deadline:
                if step == "write":
                    writer.write(image)  # again until the bridge's reader is matched and answered
                else:
                    writer.dispose(image)
                    break
                client.wait_idle(0.5)
            if step == "write":
                assert b.counts["published"] > published
    assert not unraisable
