"""`netapp ros2` from a netapp whose results carry masks, keypoints and classes: beside its Detection2DArray, the
bridge publishes foxglove_msgs/msg/ImageAnnotations stamped like each image, with the keypoints as POINTS and the
masks as filled polygons, which a ROS 2 subscriber (here cyclonedds with ROS 2's names) reads."""

from __future__ import annotations

import pytest

pytest.importorskip("cyclonedds")
pytest.importorskip("rosbags")

from netapp.results import MASK_ALPHA, polygons_to_array  # noqa: E402
from netapp.ros.bridge import DETECTIONS_DEPTH, dds_topic  # noqa: E402
from netapp.ros.foxglove import POINTS  # noqa: E402
from tests.support.bags import PERIOD_NS, START_NS  # noqa: E402
from tests.support.bridge_run import run_bridge  # noqa: E402
from tests.support.result_processors import UNSURE_KEYPOINT, SceneProcessor, dog_mask, person_keypoints  # noqa: E402

COUNT = 120  # 6 s of camera at 20 Hz (tests/support/dds_publisher.py: 160x160 grey)
SIDE = 160
IMAGES, ANNOTATIONS = "/camera/scene", "/netapp/scene_annotations"  # apart from other tests' topics


def test_the_bridge_publishes_masks_and_keypoints_as_image_annotations(serve):
    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from netapp.ros.dds_types import ImageAnnotations_

    server = serve(SceneProcessor())
    participant = DomainParticipant(0)
    qos = Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(DETECTIONS_DEPTH))
    reader = DataReader(participant, Topic(participant, dds_topic(ANNOTATIONS), ImageAnnotations_), qos=qos)
    received, _, _ = run_bridge(
        server.url, reader, IMAGES, 5, COUNT, "--annotations-topic", ANNOTATIONS, "--detections-topic", "/netapp/sd"
    )
    assert len(received) >= 5
    stamps = {START_NS + i * PERIOD_NS for i in range(COUNT)}
    sure = [v for i, k in enumerate(person_keypoints(SIDE, SIDE)) if i != UNSURE_KEYPOINT for v in k[:2]]
    for message in received:
        (keypoints,) = [a for a in message.points if a.type == POINTS]
        assert keypoints.timestamp.sec * 10**9 + keypoints.timestamp.nanosec in stamps
        assert [v for p in keypoints.points for v in (p.x, p.y)] == pytest.approx(sure, abs=0.2)
        person_polygon, dog_outline = [a for a in message.points if a.fill_color.a == MASK_ALPHA]
        traced = polygons_to_array([[v for p in dog_outline.points for v in (p.x, p.y)]], SIDE, SIDE)
        truth = dog_mask(SIDE, SIDE)
        assert (traced & truth).sum() / (traced | truth).sum() > 0.9  # the RLE, traced at the image's size
        assert "golden retriever 0.60, labrador 0.30, tench 0.01" in [t.text for t in message.texts]
