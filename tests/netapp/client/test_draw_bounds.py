"""What the robot's drawing (and `netapp stream --save`) draws is bounded, and readable (issue 45 row 13, issue 44
item 3): masks past a pixel budget are left undrawn, so no result can stall it; captions stay below the latency
banner and apart from each other; small scores read as numbers, not `0.00`."""

from __future__ import annotations

import time

import numpy as np
from pycocotools import mask as coco_mask

from netapp.client.draw import caption_height, class_colour, draw_detections, draw_result
from netapp.client.netapp_client import Result
from netapp.detections import label_text
from netapp.results import MAX_MASK_SIDE, bound_detections


def square_rle(side: int, inside: int) -> dict:
    """A valid compressed RLE of a side x side mask holding one inside x inside square at its top left."""
    counts = []
    for _ in range(inside):  # column-major: each of the first columns has `inside` pixels in, the rest out
        counts += [0, inside] if not counts else [side - inside, inside]
    counts.append(side * side - sum(counts))
    encoded = coco_mask.frPyObjects({"size": [side, side], "counts": counts}, side, side)
    return {"size": [side, side], "counts": encoded["counts"].decode("ascii")}


def test_huge_rle_masks_within_the_wire_bounds_do_not_stall_the_drawing():
    rle = square_rle(MAX_MASK_SIDE, 64)
    detections = [
        {"bbox": [0, 0, 10, 10], "score": 0.5, "class": k, "class_name": "x", "mask": {"rle": rle}} for k in range(300)
    ]
    assert bound_detections(detections)[1] == []  # each is a mask the netapp may send
    frame = np.zeros((480, 640, 3), np.uint8)
    start = time.perf_counter()
    out = draw_result(frame, Result(1, detections, 20.0, {}, None))
    assert time.perf_counter() - start < 5.0
    assert out.any()


def test_captions_stay_below_the_latency_banner():
    frame = np.zeros((240, 320, 3), np.uint8)
    detection = {"bbox": [10, 0, 200, 200], "score": 0.91, "class": 3, "class_name": "car"}
    out = draw_result(frame, Result(1, [detection], 20.0, {}, None))
    banner = caption_height(frame)
    below = out[banner : banner + 10, 12:40]  # the caption's band, just under the banner, in the class colour
    assert (below == np.array(class_colour(3))).all(axis=2).mean() > 0.5


def test_captions_of_boxes_in_one_place_are_kept_apart():
    frame = np.zeros((240, 320, 3), np.uint8)
    box = [60, 100, 200, 200]
    detections = [
        {"bbox": box, "score": 0.9, "class": 2, "class_name": "car"},
        {"bbox": box, "score": 0.8, "class": 7, "class_name": "car"},  # the same width of caption
    ]
    out = draw_detections(frame, detections)
    for class_id in (2, 7):  # both captions' bands are seen, each a whole band of its colour
        assert (out == np.array(class_colour(class_id))).all(axis=2).sum() > 150, class_id


def test_small_scores_are_readable():
    assert label_text("dog", 0.0034) == "dog 0.0034"
    assert label_text("dog", 0.00001234) == "dog 1.2e-05"
    assert label_text("dog", 0.91) == "dog 0.91" and label_text("dog", 0.0) == "dog 0.00"


def test_a_huge_class_name_is_cut_before_it_is_drawn():
    frame = np.zeros((240, 320, 3), np.uint8)
    name = "n" * 10_000_000
    detection = {"bbox": [10, 50, 200, 200], "score": 0.5, "class": 1, "class_name": name}
    message = {"classifications": [{"class": 1, "class_name": name, "score": 0.5}]}
    start = time.perf_counter()
    draw_result(frame, Result(1, [detection] * 20, 20.0, message, None))
    assert time.perf_counter() - start < 1.0
