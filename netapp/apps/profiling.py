"""Measure a model's accuracy profile: how its results change as frames get smaller or more compressed, against the
same frames at full size without compression, and what each setting costs in bytes (`netapp.accuracy`).

A setting resizes the frame (aspect kept, as the robot does: `netapp.client.sender.shrink`) so its long side is at
most that many pixels, encodes it as JPEG at that quality, decodes it, runs the model, and takes the results back
to the source's pixels, as a robot that downsizes its frames would. Boxes give F1 (matched at IoU >= 0.5, same
class); masks the mean IoU of the matched pairs' masks; keypoints their mean OKS (`netapp.models.matching`).

H.264 (`measure_h264`): a clip of consecutive frames at the robot's frame rate (a video codec's bytes depend on what
changed since the last frame, so evenly spaced samples would not do), resized the same way, encoded as one stream at
each bitrate by the robot's own encoder (`netapp.client.h264`), decoded as the netapp decodes it, each frame's
results against the same frame at full quality.
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


def clip_frames(media: str | Path, count: int, fps: float) -> list[np.ndarray]:
    """The first `count` frames of a video as a robot reads it at `fps` (`netapp.client.sources.open_source`)."""
    from netapp.client.sources import open_source

    frames = []
    for frame in open_source(str(media), fps):
        frames.append(frame)
        if len(frames) >= max(1, min(count, MAX_FRAMES)):
            break
    return frames


def as_h264_stream(frames: Sequence[np.ndarray], bitrate_kbps: int, fps: float) -> tuple[list[np.ndarray], list[int]]:
    """The frames as one H.264 stream at `bitrate_kbps` shows them to the netapp (decoded), and each one's bytes."""
    import av

    from netapp.client import h264

    h, w = frames[0].shape[:2]
    encoder = h264.H264Encoder(w - w % 2, h - h % 2, fps=round(fps), bitrate_kbps=bitrate_kbps)
    from av.codec.context import Flags

    decoder = av.CodecContext.create("h264", "r")
    decoder.thread_count = 1  # as the netapp decodes (`netapp.server.decoding.h264`): each picture out at once
    decoder.flags |= Flags.low_delay
    decoded, sizes = [], []
    for frame in frames:
        data, _ = encoder.encode(np.ascontiguousarray(frame[: encoder.height, : encoder.width]))
        sizes.append(len(data))
        pictures = decoder.decode(av.Packet(data)) if data else []  # an access unit is a packet (parse would hold it)
        decoded.append(pictures[-1].to_ndarray(format="bgr24") if pictures else np.zeros_like(frame))
    encoder.close()
    return decoded, sizes


def measure_h264(
    detect: Detect,
    frames: Sequence[np.ndarray],
    sides: Sequence[int | None],
    bitrates: Sequence[int],
    fps: float,
    progress: Callable[[Setting], None] | None = None,
) -> list[Setting]:
    """Every setting of `sides` x `bitrates` (kbit/s) for the clip `frames` (consecutive, at `fps`) as an H.264
    stream, against the frames at full size, uncompressed; bytes per frame the mean (keyframes included)."""
    reference = [detect(frame) for frame in frames]
    source = _size(frames[0])
    settings = []
    for long_side in [s for s in sides if s is None or s < max(source)]:
        scale = 1.0 if long_side is None else long_side / max(source)
        size = (round(source[0] * scale), round(source[1] * scale))
        small = [frame if scale == 1.0 else shrink(frame, size) for frame in frames]
        for bitrate in bitrates:
            decoded, sizes = as_h264_stream(small, bitrate, fps)
            compared = [
                frame_agreement(
                    in_source_pixels(found, source, source),
                    in_source_pixels(detect(image), _size(image), source),
                    frame_size=source,
                )
                for image, found in zip(decoded, reference, strict=True)
            ]
            summary = agreement(compared)
            setting = Setting(
                long_side,
                0,
                round(summary.f1, 4),
                round(statistics.fmean(sizes), 1),
                None if summary.mask_iou is None else round(summary.mask_iou, 4),
                None if summary.oks is None else round(summary.oks, 4),
                "h264",
                bitrate,
            )
            settings.append(setting)
            if progress is not None:
                progress(setting)
    return settings


H264_SIDES = (640, 416, 320, 256)
H264_BITRATES = (400, 250, 200, 160, 120, 80)  # kbit/s: 5 KB down to 1 KB a frame at 10 fps


def make_profile(
    model: str | Path,
    name: str,
    detect: Detect,
    media: str | Path,
    frames: int = 40,
    sides: Sequence[int | None] = (None, 1280, 960, 640, 416, 320, 256),
    qualities: Sequence[int] = (95, 85, 70, 50, 35, 20),
    progress: Callable[[Setting], None] | None = None,
    fps: float = 10.0,
    h264_frames: int = 100,
) -> AccuracyProfile:
    """The profile of the model file `model` (its processor `name` and `detect`) measured on `media`: JPEG on
    `frames` samples, H.264 (with PyAV, from a video) on a clip of `h264_frames` at `fps`."""
    sampled = sample_frames(media, frames)
    h, w = sampled[0].shape[:2]
    return AccuracyProfile(
        name,
        Path(media).name,
        (w, h),
        len(sampled),
        datetime.date.today().isoformat(),
        tuple(
            measure(detect, sampled, sides, qualities, progress)
            + _h264_settings(detect, media, h264_frames, fps, progress)
        ),
        sha256_of(Path(model)),
        fps,
    )


def _h264_settings(
    detect: Detect, media: str | Path, frames: int, fps: float, progress: Callable[[Setting], None] | None
) -> list[Setting]:
    """The H.264 rows: none for images (no stream to measure) or without PyAV (the profile stays JPEG's)."""
    if Path(media).is_dir() or Path(media).suffix.lower() in IMAGE_SUFFIXES:
        return []
    try:
        import av  # noqa: F401
    except ImportError:
        return []
    return measure_h264(detect, clip_frames(media, frames, fps), H264_SIDES, H264_BITRATES, fps, progress)
