"""netapp.models.preprocess.letterbox against its definition written the plain way (resize, pad, HWC -> CHW, scale):
the same blob, for YOLOX's layout (bottom-right pad, BGR 0-255) and Ultralytics' (centred, RGB 0-1), any shape."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from netapp.models.preprocess import letterbox


def plain(image: np.ndarray, size: tuple[int, int], center: bool, rgb: bool, scale: float) -> np.ndarray:
    in_h, in_w = size
    h, w = image.shape[:2]
    ratio = min(in_h / h, in_w / w)
    new_w, new_h = max(1, round(w * ratio)), max(1, round(h * ratio))
    resized = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_LINEAR) if (new_w, new_h) != (w, h) else image
    if rgb:
        resized = resized[..., ::-1]
    x0 = int(round((in_w - new_w) / 2 - 0.1)) if center else 0
    y0 = int(round((in_h - new_h) / 2 - 0.1)) if center else 0
    blob = np.full((1, 3, in_h, in_w), 114.0 * scale, np.float32)
    blob[0, :, y0 : y0 + new_h, x0 : x0 + new_w] = resized.transpose(2, 0, 1).astype(np.float32) * np.float32(scale)
    return blob


@pytest.mark.parametrize("shape", [(480, 640), (640, 480), (416, 416), (1, 1), (3, 1000), (97, 33)])
@pytest.mark.parametrize("center,rgb,scale", [(False, False, 1.0), (True, True, 1 / 255)])
def test_the_blob_is_the_plain_letterbox(shape, center, rgb, scale):
    image = np.random.default_rng(sum(shape)).integers(0, 256, (*shape, 3), dtype=np.uint8)
    for size in ((416, 416), (64, 96)):
        blob, placement = letterbox(image, size, center=center, rgb=rgb, scale=scale)
        assert blob.dtype == np.float32 and blob.flags.c_contiguous
        np.testing.assert_allclose(blob, plain(image, size, center, rgb, scale), rtol=0, atol=1e-6)
        assert (placement.width, placement.height) == (shape[1], shape[0])
