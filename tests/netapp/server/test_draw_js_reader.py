"""The pages' one reader of a result's detections (`readDetections` in draw.js), in a real headless chromium: it reads
what `netapp.detections.Detections` reads (the same boxes, labels, oriented boxes' corners, masks and keypoints) and
leaves out what it leaves out."""

from __future__ import annotations

import json

import numpy as np
import pytest

from netapp.detections import Detections
from tests.support.result_processors import HOSTILE_FIELDS, scene

DRAW_JS = "netapp/server/ui/static/draw.js"


def read_in_page(chromium, detections) -> list[dict]:
    page = chromium.new_page()
    try:
        page.set_content("<html><body></body></html>")
        page.add_script_tag(path=DRAW_JS)
        return page.evaluate(f"readDetections({json.dumps(detections)})")
    finally:
        page.close()


def test_the_page_reads_a_result_as_the_python_type_does(chromium):
    hostile = [{"bbox": [1, 1, 9, 9], "class": 1, name: value} for name, value, _ in HOSTILE_FIELDS]
    wire = [*scene(640, 480)["detections"], "junk", {"bbox": [1, 2]}, {"bbox": [0, 0, 1, float("inf")]}, *hostile]
    wire = json.loads(json.dumps(wire).replace("Infinity", "1e999"))  # JSON's way to an infinite number
    read = read_in_page(chromium, wire)
    ours = Detections.from_wire(wire, strict=False)
    assert len(read) == len(ours) == 2 + len(hostile)  # the junk, the short box and the infinite one left out
    assert [d["bbox"] for d in read] == ours.xyxy.tolist()
    assert [d["label"] for d in read] == [ours.label(i) for i in range(len(ours))]
    person = read[0]
    np.testing.assert_allclose(person["rbox"], ours.rbox_corners()[0], atol=1e-9)  # the oriented box, read once
    assert [d["rbox"] is not None for d in read] == ours.has_rbox().tolist()
    assert [d["keypoints"] is not None for d in read] == ours.has_keypoints().tolist()
    assert [d["mask"] is not None for d in read] == ours.has_mask().tolist()
    assert "runs" in read[1]["mask"]  # the dog's RLE, its runs read (and checked) once


@pytest.mark.parametrize("counts", ["!!", "0"])
def test_an_rle_whose_runs_do_not_add_up_is_no_mask(chromium, counts):
    (read,) = read_in_page(chromium, [{"bbox": [0, 0, 4, 4], "mask": {"rle": {"size": [4, 4], "counts": counts}}}])
    assert read["mask"] is None and read["bbox"] == [0, 0, 4, 4]


def test_the_pages_bounds_are_the_netapps(chromium):
    from netapp import results

    page = chromium.new_page()
    try:
        page.set_content("<html><body></body></html>")
        page.add_script_tag(path=DRAW_JS)
        bounds = page.evaluate("BOUNDS")
    finally:
        page.close()
    assert bounds == {
        "polygons": results.MAX_POLYGONS,
        "polygon_points": results.MAX_POLYGON_POINTS,
        "rle_chars": results.MAX_RLE_CHARS,
        "mask_side": results.MAX_MASK_SIDE,
        "keypoints": results.MAX_KEYPOINTS,
    }
