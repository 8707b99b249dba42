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


# -- masks, keypoints, oriented boxes and classifications --------------------------------------------------------


def scene_frame():
    from tests.support.result_processors import scene

    message = scene(640, 480)
    frame = np.full((480, 640, 3), 90, np.uint8)
    return frame, message, draw_result(frame, Result(1, message["detections"], 12.0, message))


def blended(colour, base=90):
    from netapp.client.draw import MASK_ALPHA

    return np.round(MASK_ALPHA * np.array(colour) + (1 - MASK_ALPHA) * base)


def test_masks_are_a_translucent_fill_in_the_class_colour():
    from tests.support.result_processors import DOG, PERSON, dog_box, person_box

    _, _, out = scene_frame()
    x1, y1, x2, y2 = person_box(640, 480)
    # inside the diamond (polygons), below the skeleton's hips: the person's colour through the picture
    assert np.abs(out[int(y1 + 0.62 * (y2 - y1)), int((x1 + x2) / 2)] - blended(class_colour(PERSON))).max() <= 2
    assert (out[int(y2) - 10, int(x1) + 5] == 90).all()  # a corner of the box, outside the diamond: untouched
    x1, y1, x2, y2 = dog_box(640, 480)
    assert np.abs(out[int((y1 + y2) / 2), int((x1 + x2) / 2)] - blended(class_colour(DOG))).max() <= 2  # the RLE
    assert (out[int(y1) + 4, int(x1) + 4] == 90).all()  # outside the ellipse, inside the box


def person_caption() -> tuple[int, int, int, int]:
    """Where the scene's person caption lies: just below the banner's two lines (latency, classes)."""
    from netapp.client.draw import caption_height, caption_place
    from tests.support.result_processors import person_box

    frame = np.zeros((480, 640, 3), np.uint8)
    _, rect, _ = caption_place(
        "person 0.90", np.array(person_box(640, 480)), 0.6, caption_height(frame, 2), (480, 640), []
    )
    return rect


def test_keypoints_are_dots_joined_by_the_skeleton_and_unsure_ones_are_left_out():
    from tests.support.result_processors import PERSON, UNSURE_KEYPOINT, person_keypoints

    _, _, out = scene_frame()
    points = person_keypoints(640, 480)
    left, upper, right, lower = person_caption()
    for i, (x, y, _) in enumerate(points):
        pixel = out[int(round(y)), int(round(x))]
        if left <= x <= right and upper <= y <= lower:
            continue  # under the person's caption, kept below the two lines of the banner (issue 44)
        if i == UNSURE_KEYPOINT:
            assert not (pixel == 255).all()
        else:
            assert (pixel == 255).all(), i  # a white dot
    (ax, ay, _), (bx, by, _) = points[11], points[13]  # the left hip to the left knee
    middle = out[int(round((ay + by) / 2)), int(round((ax + bx) / 2))]
    assert np.abs(middle - np.array(class_colour(PERSON))).max() <= 40  # a limb (anti-aliased)


def test_an_oriented_box_and_the_classes_are_drawn():
    from netapp.results import rbox_corners

    _, message, out = scene_frame()
    corners = rbox_corners(message["detections"][0]["rbox"])
    (ax, ay), (bx, by) = corners[1], corners[2]  # the middle of its right side
    assert (out[int(round((ay + by) / 2)), int(round((ax + bx) / 2))] != 90).any()
    band = out[20:48, :300]
    assert (band == 255).any() and (band == 0).any()  # the classes' caption, white on black, below the latency


def test_malformed_fields_are_skipped_and_never_raise():
    from tests.support.result_processors import HOSTILE_FIELDS

    frame = np.zeros((240, 320, 3), np.uint8)  # room for the ten captions, kept apart, beside their boxes
    detections = [{"bbox": [1, 1, 9, 9], "class": "x", name: value} for name, value, _ in HOSTILE_FIELDS]
    detections.append({"bbox": [20, 20, 30, 30], "mask": {"rle": {"size": [240, 320], "counts": "!!"}}})
    out = draw_result(frame, Result(1, detections, 1.0, {"classifications": "junk"}))
    assert not out[120:, 160:].any()  # boxes and the captions only


def test_coordinates_no_frame_holds_are_clipped_or_skipped_never_raised_on():
    frame = np.zeros((50, 50, 3), np.uint8)
    huge = [
        {"bbox": [0, 0, 1e300, 5]},
        {"bbox": [0, 0, float("inf"), 5]},
        {"bbox": [0, 0, float("nan"), 5]},
        {"bbox": [0, 0, "a", 5]},
        {"bbox": [[1], 0, 2, 5]},
        {"bbox": [0, 0, 5, 5], "keypoints": [[1e300, 1, 1]], "rbox": [1e300, 1, 1, 1, 1]},
        {"bbox": [0, 0, 5, 5], "mask": {"polygons": [[1e300, 1, 2, 2, 3, 3]]}},
    ]
    out = draw_detections(frame, huge)
    assert out[0, 10].any()  # the first box's top edge, clipped to the frame
