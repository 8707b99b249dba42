"""The live page draws masks (polygons, and RLE decoded in the page), keypoints with the skeleton's limbs, oriented
boxes and an image classification's classes, in a real headless chromium, from a real netapp serving a custom
processor; checked by the canvas's pixels (and a screenshot to look at, in the test's temporary folder)."""

from __future__ import annotations

import json

import numpy as np
import requests

from netapp.client.draw import class_colour
from netapp.results import MASK_ALPHA
from tests.netapp.server.test_ui import Robot, canvas_pixels, colour_distance
from tests.support.polling import wait_until
from tests.support.result_processors import (
    DOG,
    PERSON,
    UNSURE_KEYPOINT,
    SceneProcessor,
    dog_box,
    person_box,
    person_keypoints,
)

WIDTH, HEIGHT, GREY = 640, 480, 90


def blend(class_id: int) -> tuple[int, int, int]:
    b, g, r = class_colour(class_id)
    return tuple(round(MASK_ALPHA * c + (1 - MASK_ALPHA) * GREY) for c in (r, g, b))


def test_the_page_draws_masks_keypoints_rboxes_and_classes(chromium, serve, tmp_path):
    server = serve(SceneProcessor())
    robot = Robot(server.url, np.full((HEIGHT, WIDTH, 3), GREY, np.uint8), "mask-bot")
    page = chromium.new_page(viewport={"width": 900, "height": 1000})
    try:
        wait_until(lambda: robot.client.stats.results >= 1, what="results")
        (entry,) = requests.get(server.url + "/ui/api/robots", timeout=5).json()["robots"]
        page.goto(f"{server.url}/ui/robot/{entry['id']}")
        page.wait_for_function("Number(document.body.dataset.frames) >= 2", timeout=20_000)

        person, dog = (page.locator(f"#detections li[data-class='{c}']").first for c in (PERSON, DOG))
        assert person.get_attribute("data-mask") == "polygons" and person.get_attribute("data-keypoints") == "17"
        assert dog.get_attribute("data-mask") == "rle"
        assert page.locator("#classes li").all_inner_texts() == ["golden retriever 0.60", "labrador 0.30", "tench 0.01"]

        def pixel(x: float, y: float) -> list[int]:
            return canvas_pixels(page, round(x), round(y), 1)[0]

        x1, y1, x2, y2 = dog_box(WIDTH, HEIGHT)  # the RLE ellipse, decoded by the page
        assert colour_distance(pixel((x1 + x2) / 2, (y1 + y2) / 2), blend(DOG)) <= 8
        assert colour_distance(pixel(x1 + 6, y1 + 6), (GREY,) * 3) <= 8  # a corner of its box, outside the mask
        x1, y1, x2, y2 = person_box(WIDTH, HEIGHT)  # the polygon: a diamond in the person's box
        assert colour_distance(pixel((x1 + x2) / 2, y1 + 0.62 * (y2 - y1)), blend(PERSON)) <= 8
        assert colour_distance(pixel(x1 + 6, y2 - 6), (GREY,) * 3) <= 8
        for i, (x, y, _) in enumerate(person_keypoints(WIDTH, HEIGHT)):  # white dots, but not the unsure wrist
            white = colour_distance(pixel(x, y), (255, 255, 255)) <= 10
            assert white == (i != UNSURE_KEYPOINT), i
        hip, knee = person_keypoints(WIDTH, HEIGHT)[11], person_keypoints(WIDTH, HEIGHT)[13]
        b, g, r = class_colour(PERSON)
        limb = canvas_pixels(page, round((hip[0] + knee[0]) / 2) - 2, round((hip[1] + knee[1]) / 2), 5)
        assert min(colour_distance(p, (r, g, b)) for p in limb) <= 40  # the left thigh

        output = page.locator("#output")
        assert not output.is_visible() or "classifications" not in output.inner_text()
        page.screenshot(path=str(tmp_path / "ui-masks.png"), full_page=True)  # docs/ui-masks.png is one
        events = json.loads(page.evaluate("JSON.stringify(STYLE)"))
        assert events["mask_alpha"] == MASK_ALPHA and len(events["coco_skeleton"]) == 19  # from the netapp
    finally:
        page.close()
        robot.close()
