"""`netapp watch URL --source NAME --ros2`: a camera's results published over DDS with ROS 2's names, as the live
bridge publishes a robot's (netapp/ros/bridge.py); read here by a DDS subscriber, as a ROS 2 node would."""

from __future__ import annotations

import subprocess
import sys

import pytest

from netapp.server.settings import Settings
from netapp.server.sources.naming import parse_source
from tests.support.paths import ROOT

pytest.importorskip("cyclonedds", reason="cyclonedds is not installed (pip install 'netapp-toolkit[ros]')")


def test_a_cameras_results_reach_a_ros2_topic_stamped_and_named_after_the_camera(cameras, serve, tiny_detector):
    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    from netapp.ros.bridge import DETECTIONS_DEPTH, dds_topic
    from netapp.ros.dds_types import Detection2DArray_

    camera = cameras()
    server = serve(tiny_detector, Settings(lanes=1, sources=(parse_source(f"door={camera.url}"),)))
    participant = DomainParticipant(0)
    qos = Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(DETECTIONS_DEPTH))
    topic = "/cameras/detections"
    reader = DataReader(participant, Topic(participant, dds_topic(topic), Detection2DArray_), qos=qos)
    watch = subprocess.Popen(
        [sys.executable, "-m", "netapp", "watch", server.url, "--source", "door", "--duration", "20", "--ros2"]
        + ["--detections-topic", topic],
        cwd=ROOT,
        stderr=subprocess.PIPE,
        text=True,
    )
    arrays = []
    try:
        for sample in reader.take_iter(timeout=duration(seconds=10)):  # each within 10 s (discovery first)
            arrays.append(sample)
            if len(arrays) >= 3:
                break
    finally:
        watch.terminate()
        _, err = watch.communicate(timeout=30)
    assert len(arrays) >= 3, err
    stamps = [a.header.stamp.sec * 10**9 + a.header.stamp.nanosec for a in arrays]
    assert stamps == sorted(stamps) and stamps[0] > 1.7e18  # when the netapp decoded each picture, since the epoch
    for array in arrays:
        assert array.header.frame_id == "door"
        (detection,) = array.detections  # the tiny model's one robot
        assert detection.results[0].hypothesis.class_id == "robot"
