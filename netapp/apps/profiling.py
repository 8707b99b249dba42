"""Measure a model's accuracy profile: how its results change as frames get smaller or more compressed, against the
same frames at full size without compression, and what each setting costs in bytes (`netapp.accuracy`).

A setting resizes the frame (aspect kept, as the robot does: `netapp.client.sender.shrink`) so its long side is at
most that many pixels, encodes it as JPEG at that quality, decodes it, runs the model, and takes the results back
to the source's pixels, as a robot that downsizes its frames would. Boxes give F1 (matched at IoU >= 0.5, same
class); masks the mean IoU of the matched pairs' masks; keypoints their mean OKS (`netapp.models.matching`).
"""

from __future__ import annotations

import datetime
import statistics
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from netapp.accuracy import AccuracyProfile, Setting
from netapp.client.sender import shrink
from netapp.detections import Detections
from netapp.models.matching import FrameAgreement, agreement, frame_agreement
from netapp.models.source import sha256_of

Detect = Callable[[np.ndarray], list[dict[str, Any]]]  # a frame (BGR) -> its detections in the wire form
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".webp")
MAX_FRAMES = 1000  # a profile is a sample: more frames than this only take longer


def sample_frames(media: str | Path, count: int) -> list[np.ndarray]:
    """`count` frames taken evenly through a video, or the first `count` images of an image or a folder of images;
    ValueError saying what to give when none can be read."""
    path = Path(media)
    count = max(1, min(count, MAX_FRAMES))
    if path.is_dir() or path.suffix.lower() in IMAGE_SUFFIXES:
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES) if path.is_dir() else [path]
        frames = [f for f in (cv2.imread(str(p), cv2.IMREAD_COLOR) for p in files[:count]) if f is not None]
    else:
        frames = _video_frames(str(path), count)
    if not frames:
        raise ValueError(f"no frames could be read from {media}: give a video, an image or a folder of images")
    return frames


def _video_frames(video: str, count: int) -> list[np.ndarray]:
    capture = cv2.VideoCapture(video)
    total = 0  # counted, not read from the container: it may claim more frames than decode (pedestrians.avi: 2x)
    while capture.grab():
        total += 1
    capture.release()
    capture = cv2.VideoCapture(video)
    wanted = {round(i * total / count) for i in range(count)}
    frames, index = [], 0
    while len(frames) < len(wanted):
        ok, frame = capture.read()
        if not ok:
            break
        if index in wanted:
            frames.append(frame)
        index += 1
    capture.release()
    return frames


def at_setting(frame: np.ndarray, long_side: int | None, quality: int) -> tuple[np.ndarray, int]:
    """The frame as the netapp would get it at this setting (decoded), and its JPEG size in bytes."""
    h, w = frame.shape[:2]
    scale = 1.0 if long_side is None or long_side >= max(h, w) else long_side / max(h, w)
    small = frame if scale == 1.0 else shrink(frame, (round(w * scale), round(h * scale)))  # as the robot sends it
    data = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, quality])[1]
    return cv2.imdecode(data, cv2.IMREAD_COLOR), len(data)


def in_source_pixels(
    detections: Sequence[dict[str, Any]], seen: tuple[int, int], source: tuple[int, int]
) -> Detections:
    """Detections found in a frame of `seen` (width, height) taken to `source` pixels for comparison (boxes,
    polygons and keypoints scaled; an RLE mask is resized when it is decoded, `frame_agreement`'s `frame_size`)."""
    return Detections.from_wire(list(detections), strict=False).scaled(source[0] / seen[0], source[1] / seen[1])


def _size(frame: np.ndarray) -> tuple[int, int]:
    return frame.shape[1], frame.shape[0]


def measure(
    detect: Detect,
    frames: Sequence[np.ndarray],
    sides: Sequence[int | None],
    qualities: Sequence[int],
    progress: Callable[[Setting], None] | None = None,
) -> list[Setting]:
    """Every setting of `sides` x `qualities` against the frames at full size, uncompressed. A long side at or
    above the source's own is the source's size: measured once, as `full` (None)."""
    reference = [detect(frame) for frame in frames]
    source_long = max(frames[0].shape[:2])
    settings = []
    for long_side in [s for s in sides if s is None or s < source_long]:
        for quality in qualities:
            compared: list[FrameAgreement] = []
            sizes = []
            for frame, found in zip(frames, reference, strict=True):
                image, size = at_setting(frame, long_side, quality)
                source = _size(frame)
                ref = in_source_pixels(found, source, source)
                found_here = in_source_pixels(detect(image), _size(image), source)
                compared.append(frame_agreement(ref, found_here, frame_size=source))
                sizes.append(size)
            summary = agreement(compared)
            setting = Setting(
                long_side,
                quality,
                round(summary.f1, 4),
                round(statistics.median(sizes), 1),
                None if summary.mask_iou is None else round(summary.mask_iou, 4),
                None if summary.oks is None else round(summary.oks, 4),
            )
            settings.append(setting)
            if progress is not None:
                progress(setting)
    return settings


def make_profile(
    model: str | Path,
    name: str,
    detect: Detect,
    media: str | Path,
    frames: int = 40,
    sides: Sequence[int | None] = (None, 1280, 960, 640, 416, 320, 256),
    qualities: Sequence[int] = (95, 85, 70, 50, 35, 20),
    progress: Callable[[Setting], None] | None = None,
) -> AccuracyProfile:
    """The profile of the model file `model` (its processor `name` and `detect`) measured on `media`."""
    sampled = sample_frames(media, frames)
    h, w = sampled[0].shape[:2]
    return AccuracyProfile(
        name,
        Path(media).name,
        (w, h),
        len(sampled),
        datetime.date.today().isoformat(),
        tuple(measure(detect, sampled, sides, qualities, progress)),
        sha256_of(Path(model)),
    )
