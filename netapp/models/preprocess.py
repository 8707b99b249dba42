"""From a robot's BGR frame to a model's input blob, and back: letterbox (YOLO), stretch (DETR family), or the
classifiers' shorter-side resize and centre crop; `Placement` maps model-input pixels back to the frame's."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

PAD_VALUE = 114.0  # the grey every YOLO letterbox pads with


@dataclass(frozen=True)
class Placement:
    """Where a frame sits in the model input: input = frame * scale + pad, per axis."""

    scale_x: float
    scale_y: float
    pad_x: float
    pad_y: float
    width: int  # the frame's size
    height: int

    def points_to_frame(self, xy: np.ndarray, clip: bool = True) -> np.ndarray:
        """... x 2 points in model-input pixels -> frame pixels, clipped to the frame unless told not to."""
        out = np.empty(xy.shape, np.float32)
        out[..., 0] = (xy[..., 0] - self.pad_x) / self.scale_x
        out[..., 1] = (xy[..., 1] - self.pad_y) / self.scale_y
        if clip:
            np.clip(out[..., 0], 0, self.width, out=out[..., 0])
            np.clip(out[..., 1], 0, self.height, out=out[..., 1])
        return out

    def boxes_to_frame(self, boxes_xyxy: np.ndarray) -> np.ndarray:
        """N x 4 boxes in model-input pixels -> frame pixels, clipped to the frame (as Ultralytics' scale_boxes)."""
        return self.points_to_frame(boxes_xyxy.reshape(-1, 2, 2)).reshape(-1, 4)


def letterbox(
    image: np.ndarray, size: tuple[int, int], *, center: bool, rgb: bool, scale: float, pad_value: float = PAD_VALUE
) -> tuple[np.ndarray, Placement]:
    """BGR uint8 HxWx3 -> float32 1x3xHxW blob and the placement.

    YOLOX pads at the bottom-right, takes BGR 0-255; Ultralytics exports centre the image and take RGB 0-1.
    """
    in_h, in_w = size
    h, w = image.shape[:2]
    ratio = min(in_h / h, in_w / w)
    new_w, new_h = max(1, round(w * ratio)), max(1, round(h * ratio))
    resized = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_LINEAR) if (new_w, new_h) != (w, h) else image
    pad_x = (in_w - new_w) / 2 if center else 0.0
    pad_y = (in_h - new_h) / 2 if center else 0.0
    x0, y0 = int(round(pad_x - 0.1)), int(round(pad_y - 0.1))
    # One plane at a time (OpenCV splits HWC into planes): each is copied into the blob row by row, and only the
    # border is filled, a quarter less time than one strided HWC -> CHW copy into a filled blob.
    blob = np.empty((1, 3, in_h, in_w), dtype=np.float32)
    planes = cv2.split(resized)
    pad = pad_value * scale
    for channel, plane in enumerate(reversed(planes) if rgb else planes):
        out = blob[0, channel]
        out[:y0], out[y0 + new_h :] = pad, pad
        out[y0 : y0 + new_h, :x0], out[y0 : y0 + new_h, x0 + new_w :] = pad, pad
        inside = out[y0 : y0 + new_h, x0 : x0 + new_w]
        if scale != 1.0:
            cv2.multiply(plane, scale, dst=inside, dtype=cv2.CV_32F)
        else:
            inside[...] = plane
    return blob, Placement(ratio, ratio, float(x0), float(y0), w, h)


def to_blob(
    image: np.ndarray, *, rgb: bool, scale: float, mean: tuple[float, ...] | None, std: tuple[float, ...] | None
) -> np.ndarray:
    """HxWx3 uint8 BGR -> 1x3xHxW float32: channel order, scale, then (x - mean) / std when given."""
    pixels = image[..., ::-1] if rgb else image
    blob = pixels.transpose(2, 0, 1)[None].astype(np.float32)
    if scale != 1.0:
        blob /= np.float32(1 / scale)  # a division, as torchvision's ToTensor: the exporter's input to the bit
    if mean is not None and std is not None:
        blob -= np.asarray(mean, np.float32).reshape(1, 3, 1, 1)
        blob /= np.asarray(std, np.float32).reshape(1, 3, 1, 1)
    return blob


def stretch(
    image: np.ndarray,
    size: tuple[int, int],
    *,
    rgb: bool = True,
    scale: float = 1 / 255,
    mean: tuple[float, ...] | None = None,
    std: tuple[float, ...] | None = None,
) -> tuple[np.ndarray, Placement]:
    """The DETR family's preprocessing: the frame resized to the input size, aspect ratio not kept."""
    in_h, in_w = size
    h, w = image.shape[:2]
    resized = cv2.resize(image, (in_w, in_h), interpolation=cv2.INTER_LINEAR) if (w, h) != (in_w, in_h) else image
    return to_blob(resized, rgb=rgb, scale=scale, mean=mean, std=std), Placement(in_w / w, in_h / h, 0.0, 0.0, w, h)


def center_crop(image: np.ndarray, size: tuple[int, int], *, rgb: bool = True, scale: float = 1 / 255) -> np.ndarray:
    """The classifiers' preprocessing (torchvision's Resize(shorter side) + CenterCrop, as Ultralytics runs it): PIL's
    antialiased bilinear resize, so the input is the exporter's own to the byte."""
    from PIL import Image

    in_h, in_w = size
    h, w = image.shape[:2]
    short = min(in_h, in_w)
    new_w, new_h = (short, int(short * h / w)) if w <= h else (int(short * w / h), short)
    resized = np.asarray(Image.fromarray(np.ascontiguousarray(image)).resize((new_w, new_h), Image.BILINEAR))
    top, left = int(round((new_h - in_h) / 2.0)), int(round((new_w - in_w) / 2.0))
    crop = resized[max(top, 0) : max(top, 0) + in_h, max(left, 0) : max(left, 0) + in_w]
    if crop.shape[:2] != (in_h, in_w):  # a frame smaller than the crop: pad as torchvision's CenterCrop does
        padded = np.zeros((in_h, in_w, 3), np.uint8)
        padded[: crop.shape[0], : crop.shape[1]] = crop
        crop = padded
    return to_blob(crop, rgb=rgb, scale=scale, mean=None, std=None)
