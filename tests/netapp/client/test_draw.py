"""The drawing helper: boxes in each class's colour where the detections are, labels, the caption; pure."""

from __future__ import annotations

import numpy as np

from netapp.client.draw import class_colour, draw_detections, draw_result, label_of, latency_caption
from netapp.client.netapp_client import Result
from netapp.client.timing import LatencyBreakdown


def test_boxes_are_drawn_in_the_class_colour_on_a_copy():
    frame = np.zeros((200, 300, 3), np.uint8)
    detection = {"bbox": [50.4, 60, 150, 180], "score": 0.91, "class": 16, "class_name": "dog"}
    out = draw_detections(frame, [detection])
    assert not frame.any()  # the robot's frame is untouched
    colour = np.array(class_colour(16))
    assert (out[120, 50] == colour).all() and (out[120, 150] == colour).all()  # left and right edges
    assert (out[179, 100] == colour).all()  # bottom edge
    assert not out[120, 100].any()  # inside stays as it was
    assert label_of(detection) == "dog 0.91"


def test_in_place_drawing_and_what_is_not_a_box_is_skipped():
    frame = np.zeros((50, 50, 3), np.uint8)
    out = draw_detections(frame, [{"label": "no bbox"}, "junk", {"bbox": [1, 2]}], copy=False)
    assert out is frame and not frame.any()


def test_classes_get_distinct_colours():
    colours = {class_colour(c) for c in range(80)}
    assert len(colours) >= 30


def test_draw_result_writes_the_latency_caption():
    frame = np.zeros((240, 320, 3), np.uint8)
    parts = LatencyBreakdown(3.2, 1.0, 25.4, 4.1, 33.7)
    result = Result(1, [], 33.7, {}, parts)
    out = draw_result(frame, result)
    assert out[:20, :200].any() and not out[100:].any()  # a caption band at the top, nothing else
    assert latency_caption(33.7, parts) == "latency 34 ms (up 3 / queue 1 / infer 25 / down 4)"
    assert latency_caption(None) == "no result yet"
