"""Frame sources for the robot side: a camera, a video file or a still image, resampled to a target rate."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".bmp", ".webp"}


class SourceError(Exception):
    pass


def open_source(source: str, fps: float, size: tuple[int, int] | None = None) -> Iterator[np.ndarray]:
    """Frames at `fps`: a video is resampled by its own timeline and loops; an image repeats; a camera streams.

    `size` (width, height) resizes every frame. The iterator is endless; the caller paces and stops it.
    """
    if source.isdigit():
        frames = _camera(int(source))
    elif Path(source).suffix.lower() in IMAGE_SUFFIXES:
        frames = _image(source)
    else:
        frames = _video(source, fps)
    for frame in frames:
        yield cv2.resize(frame, size, interpolation=cv2.INTER_AREA) if size and frame.shape[1::-1] != size else frame


def _image(path: str) -> Iterator[np.ndarray]:
    image = cv2.imread(path, cv2.IMREAD_COLOR)
    if image is None:
        raise SourceError(f"cannot read image {path}")
    while True:
        yield image


def _camera(index: int) -> Iterator[np.ndarray]:
    capture = cv2.VideoCapture(index)
    if not capture.isOpened():
        raise SourceError(f"cannot open camera {index}")
    try:
        while True:
            ok, frame = capture.read()
            if not ok:
                raise SourceError(f"camera {index} stopped delivering frames")
            yield frame
    finally:
        capture.release()


def _video(path: str, fps: float) -> Iterator[np.ndarray]:
    """Resample to `fps` by the video's own timeline: frames are skipped or repeated, and the video loops."""
    if not Path(path).is_file():
        raise SourceError(f"no such video, image or camera: {path}")
    capture = cv2.VideoCapture(path)
    if not capture.isOpened():
        raise SourceError(f"cannot open video {path}")
    step = (capture.get(cv2.CAP_PROP_FPS) or fps) / fps  # source frames per output frame
    try:
        due, index = 0.0, 0  # `index` counts source frames across loops
        while True:
            ok, frame = capture.read()
            if not ok:  # end of the video: loop
                capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
                ok, frame = capture.read()
                if not ok:
                    raise SourceError(f"video {path} has no readable frames")
            while due < index + 1:  # repeat (step < 1) or skip (step > 1) frames to keep the timeline
                yield frame
                due += step
            index += 1
    finally:
        capture.release()
