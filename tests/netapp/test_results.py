"""The result fields' wire forms and bounds (netapp/results.py)."""

import numpy as np
import pytest

from netapp import results
from netapp.results import Classification, Detection, Mask


def disc(h=120, w=160, cx=80, cy=60, r=30):
    yy, xx = np.mgrid[:h, :w]
    return (xx - cx) ** 2 + (yy - cy) ** 2 <= r * r


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


def test_polygons_round_trip_keeps_the_mask():
    mask = disc()
    wire = Mask.from_array(mask).to_wire()
    back = results.mask_to_array(wire, *mask.shape)
    assert iou(mask, back) > 0.95


def test_polygons_shift_by_origin():
    mask = disc(60, 60, 30, 30, 20)
    wire = Mask.from_array(mask, origin=(100, 50)).to_wire()
    frame = results.mask_to_array(wire, 200, 200)
    assert frame[80, 130] and not frame[30, 30]


def test_polygon_budget_is_kept_on_a_ragged_mask():
    rng = np.random.default_rng(0)
    mask = rng.random((300, 300)) > 0.5
    wire = Mask.from_array(mask, max_points=200).to_wire()
    assert sum(len(p) // 2 for p in wire["polygons"]) <= 200
    assert results.field_problem("mask", wire) is None


def test_rle_round_trip_exact():
    mask = disc()
    wire = Mask.from_array(mask, fmt="rle").to_wire()
    assert set(wire["rle"]) == {"size", "counts"} and isinstance(wire["rle"]["counts"], str)
    assert (results.mask_to_array(wire, *mask.shape) == mask).all()


def test_uncompressed_rle_decodes():
    rle = {"size": [2, 3], "counts": [1, 2, 3]}
    assert results.rle_to_array(rle).sum() == 2


@pytest.mark.parametrize(
    "rle",
    [{"size": [0, 5], "counts": ""}, {"size": [10, 10], "counts": [1, 2]}, {"size": [10], "counts": "a"},
     {"size": [10, 10], "counts": "x" * (results.MAX_RLE_CHARS + 1)}, {"size": [10, 10], "counts": 5}],
)  # fmt: skip
def test_bad_rle_is_a_value_error(rle):
    with pytest.raises(ValueError):
        results.rle_to_array(rle)


def test_detection_wire_form_keeps_the_5g_era_keys():
    d = Detection([1, 2, 3, 4], 0.5, 7, "truck", keypoints=np.array([[1.0, 2.0, 0.9]]), rbox=[5, 6, 7, 8, 0.1])
    wire = d.to_wire()
    assert wire["bbox"] == [1.0, 2.0, 3.0, 4.0] and wire["class"] == 7 and wire["class_name"] == "truck"
    assert wire["keypoints"] == [[1.0, 2.0, 0.9]] and wire["rbox"] == [5.0, 6.0, 7.0, 8.0, 0.1]
    assert Classification(3, "cat", 0.25).to_wire() == {"class": 3, "class_name": "cat", "score": 0.25}


def test_bounds_refuse_big_or_malformed_fields_and_keep_the_box():
    box = {"bbox": [0, 0, 1, 1], "score": 1.0, "class": 0, "class_name": "x"}
    big_mask = {**box, "mask": {"polygons": [[0.0, 0.0] * 600, [1.0, 1.0] * 600]}}
    many_points = {**box, "keypoints": [[0, 0, 1]] * (results.MAX_KEYPOINTS + 1)}
    nan_points = {**box, "keypoints": [[0, float("nan"), 1]]}
    bad_rbox = {**box, "rbox": [1, 2, 3]}
    fine = {**box, "keypoints": [[1, 2, 0.5]], "mask": {"polygons": [[0, 0, 1, 0, 1, 1]]}}
    kept, refused = results.bound_detections([big_mask, many_points, nan_points, bad_rbox, fine])
    assert refused == ["mask_too_big", "keypoints_too_big", "keypoints_malformed", "rbox_malformed"]
    assert kept[:4] == [box, box, box, box] and kept[4] == fine


def test_too_many_detections_are_cut_and_counted():
    box = {"bbox": [0, 0, 1, 1], "score": 1.0, "class": 0, "class_name": "x"}
    kept, refused = results.bound_detections([box] * (results.MAX_DETECTIONS + 5))
    assert len(kept) == results.MAX_DETECTIONS and refused == ["too_many_detections"] * 5


def test_rle_counts_decode_as_pycocotools_encodes():
    rng = np.random.default_rng(3)
    for i in range(60):
        h, w = (int(v) for v in rng.integers(1, 60, 2))
        mask = rng.random((h, w)) > rng.random() if i % 2 else disc(h, w, w // 2, h // 2, min(h, w) // 3)
        assert (results.rle_to_array(results.mask_to_rle(mask)) == mask).all(), i


def test_hostile_rle_strings_are_value_errors_never_a_crash():
    # pycocotools' own decoder corrupts its heap on such strings (Python aborts): ours refuses them.
    rng = np.random.default_rng(1)
    for _ in range(3000):
        counts = "".join(chr(c) for c in rng.integers(33, 127, int(rng.integers(1, 50))))
        try:
            results.rle_to_array({"size": [20, 30], "counts": counts})
        except ValueError:
            pass
    assert results.field_problem("mask", {"rle": {"size": [20, 30], "counts": "1"}}) == "mask_malformed"


def test_a_polygon_masks_reason_is_the_first_problem_in_order():
    nan_first = {"polygons": [[float("nan"), 1.0] * 3, [1.0, 2.0] * results.MAX_POLYGON_POINTS]}
    assert results.field_problem("mask", nan_first) == "mask_malformed"  # malformed before the points run out
    big_then_nan = {"polygons": [[1.0, 2.0] * results.MAX_POLYGON_POINTS, [1.0, float("inf")] * 3]}
    assert results.field_problem("mask", big_then_nan) == "mask_too_big"
    assert results.field_problem("mask", {"polygons": [[1.0, 2.0] * 3, [1.0, True] * 3]}) == "mask_malformed"
    assert results.field_problem("mask", {"polygons": [[1.0, 2.0] * 3, []]}) is None
