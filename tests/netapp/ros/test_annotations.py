"""`netapp stream --mcap` from a netapp whose results carry masks, keypoints, an oriented box and classes: the
recording opens with the `mcap` reader and its Foxglove image annotations have the keypoints as POINTS, the limbs as
a LINE_LIST, the masks as filled line loops (the RLE traced), the oriented box and the classes' caption."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

pytest.importorskip("mcap_ros2")

from netapp.cli import main as netapp_main  # noqa: E402
from netapp.results import COCO_SKELETON, MASK_ALPHA, polygons_to_array, rbox_corners  # noqa: E402
from netapp.ros.foxglove import LINE_LIST, LINE_LOOP, POINTS  # noqa: E402
from tests.support.bags import read_mcap  # noqa: E402
from tests.support.result_processors import (  # noqa: E402
    UNSURE_KEYPOINT,
    SceneProcessor,
    dog_mask,
    person_box,
    person_keypoints,
    scene,
)

WIDTH, HEIGHT = 320, 240


def xy(annotation) -> list[float]:
    """An annotation's points, flat: x, y, x, y, ..."""
    return [v for p in annotation.points for v in (p.x, p.y)]


def flat(points) -> list[float]:
    return [float(v) for p in points for v in p[:2]]


def test_the_mcap_has_keypoints_limbs_masks_and_rboxes(tmp_path, capsys, serve):
    server = serve(SceneProcessor())
    image, out = tmp_path / "grey.png", tmp_path / "out.mcap"
    cv2.imwrite(str(image), np.full((HEIGHT, WIDTH, 3), 90, np.uint8))
    argv = ["stream", server.url, "--source", str(image), "--fps", "10", "--duration", "1", "--mcap", str(out)]
    assert netapp_main(argv) == 0
    capsys.readouterr()
    (_, annotations), *_ = read_mcap(out)["/netapp/annotations"]
    by_type = {kind: [a for a in annotations.points if a.type == kind] for kind in (POINTS, LINE_LIST, LINE_LOOP)}

    (keypoints,) = by_type[POINTS]
    sure = [k for i, k in enumerate(person_keypoints(WIDTH, HEIGHT)) if i != UNSURE_KEYPOINT]
    assert xy(keypoints) == pytest.approx(flat(sure), abs=0.1)
    (limbs,) = by_type[LINE_LIST]
    whole = [pair for pair in COCO_SKELETON if UNSURE_KEYPOINT not in pair]  # a limb to the unsure wrist is left out
    assert len(limbs.points) == 2 * len(whole)

    filled = [a for a in by_type[LINE_LOOP] if a.fill_color.a == MASK_ALPHA]
    person_polygon, dog_outline = filled
    x1, y1, x2, y2 = person_box(WIDTH, HEIGHT)
    diamond = [((x1 + x2) / 2, y1), (x2, (y1 + y2) / 2), ((x1 + x2) / 2, y2), (x1, (y1 + y2) / 2)]
    assert xy(person_polygon) == pytest.approx(flat(diamond), abs=0.1)
    traced = polygons_to_array([xy(dog_outline)], HEIGHT, WIDTH)
    truth = dog_mask(WIDTH, HEIGHT)
    assert (traced & truth).sum() / (traced | truth).sum() > 0.95  # the RLE, traced at the image's size
    rbox = scene(WIDTH, HEIGHT)["detections"][0]["rbox"]
    assert any(xy(a) == pytest.approx(flat(rbox_corners(rbox)), abs=0.1) for a in by_type[LINE_LOOP])
    texts = [t.text for t in annotations.texts]
    assert "golden retriever 0.60, labrador 0.30, tench 0.01" in texts and "person 0.90" in texts
