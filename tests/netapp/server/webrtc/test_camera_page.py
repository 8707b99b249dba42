"""/camera in a real browser: Debian's chromium with a fake camera fed a y4m made from the shared video (FFmpeg), its
WebRTC track to a real netapp with YOLOX-Nano, the boxes drawn over the picture from the data channel's results."""

from __future__ import annotations

import pytest

from netapp.server.settings import Settings
from tests.netapp.server.test_frames import metric
from tests.support.fake_camera import camera_flags, fake_camera, ffmpeg_problem

pytest.importorskip("aiortc", reason="aiortc is not installed: pip install 'netapp-toolkit[webrtc]'")

BOXES_WITHIN_MS = 5000  # the goal: boxes drawn within 5 s of the page opening its camera
PERSON = 0


def test_the_camera_page_draws_boxes_over_the_browsers_camera(
    chromium_with, serve, real_model_path, media_dir, tmp_path
):
    from netapp.models import Detector, DetectorConfig

    if ffmpeg_problem():
        pytest.skip(ffmpeg_problem())
    camera = fake_camera(media_dir / "pedestrians.avi", tmp_path / "camera.y4m")
    server = serve(Detector(DetectorConfig(str(real_model_path))), Settings(lanes=1))
    browser = chromium_with(*camera_flags(camera))
    page = browser.new_page(viewport={"width": 720, "height": 620})
    try:
        page.goto(server.url + "/camera")
        page.click("#start")  # a click, as a person's: getUserMedia, the offer, the peer
        page.wait_for_function("Number(document.body.dataset.results) >= 1", timeout=BOXES_WITHIN_MS)
        page.wait_for_function("Number(document.body.dataset.boxes) >= 1", timeout=BOXES_WITHIN_MS)
        person = page.locator(f"#detections li[data-class='{PERSON}']").first
        assert person.inner_text().startswith("person ")
        x1, y1, x2, y2 = (float(v) for v in person.get_attribute("data-bbox")[1:-1].split(","))
        assert 0 <= x1 < x2 <= 640 and 0 <= y1 < y2 <= 360  # in the pixels of the picture the browser sent
        assert page.evaluate("document.body.dataset.state") == "connected"
        assert metric(server.url, 'netapp_frames_processed_total{transport="webrtc"}') >= 1
        page.screenshot(path=str(tmp_path / "camera-webrtc.png"))  # to look at; docs/camera-webrtc.png is one
    finally:
        page.close()
