"""How detection quality falls as frames get smaller or more compressed: an accuracy profile, measured once per model
(`netapp profile MODEL`, `python -m bench.accuracy`) and shipped as data, so a robot knows the cheapest setting that
keeps F1 above a floor.

A setting is a frame's long side in pixels (None: the source's own size) and a JPEG quality, or (codec "h264") an
H.264 bitrate for a stream of consecutive frames at the profile's frame rate; its F1 is against the same frames at
full size without compression (boxes matched at IoU >= 0.5, same class), its bytes the median JPEG size (H.264: the
mean access unit, keyframes included); for a model with masks or keypoints, the mean mask IoU and OKS of the matched
pairs too. A profile names its model by processor name and by the SHA-256 of the model file it was made with, so
that a netapp names only a profile made for its own model. The profile is data from the network's far side only in
the sense that it ships with the package: `AccuracyProfile.from_json` checks every field and bounds the row count
all the same. Both sides read it, so it lies below both: the netapp names the profile made for its model
(`netapp.models.profiles`), the robot's adapter follows it (`netapp.client.adapt`), and `netapp profile`
(`netapp.apps.profiling`) writes one; the shipped profiles are netapp/profiles/NAME.json.
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

PROFILES = Path(__file__).with_name("profiles")
MAX_SETTINGS = 1000
DEFAULT_F1_FLOOR = 0.9


@dataclass(frozen=True)
class Setting:
    long_side: int | None  # pixels of the frame's longer side; None: as the camera gives it
    quality: int  # JPEG quality, 1..100 (H.264: unused, 0)
    f1: float  # agreement with the full-quality run, 0..1
    bytes_per_frame: float  # median JPEG size at this setting, for the profile's source
    mask_iou: float | None = None  # mean IoU of the matched detections' masks, 0..1 (None: the model gives none)
    oks: float | None = None  # mean object keypoint similarity of the matched detections, 0..1 (None: no keypoints)
    codec: str = "jpeg"  # or "h264"
    bitrate_kbps: int | None = None  # H.264's target bitrate (at `AccuracyProfile.fps`)

    def describe(self) -> str:
        """One line: the setting and what it keeps."""
        kept = [f"F1 {self.f1:.3f}"]
        kept += [f"mask IoU {self.mask_iou:.3f}"] if self.mask_iou is not None else []
        kept += [f"OKS {self.oks:.3f}"] if self.oks is not None else []
        how = f"H.264 {self.bitrate_kbps} kbit/s" if self.codec == "h264" else f"quality {self.quality}"
        return f"long side {self.long_side or 'full'}, {how}: {', '.join(kept)}"


@dataclass(frozen=True)
class AccuracyProfile:
    model: str  # the processor's name (`describe()["name"]`), e.g. yolox_nano
    source: str  # what it was measured on (a file name), at `source_size`
    source_size: tuple[int, int]  # width, height
    frames: int
    measured: str  # a date
    settings: tuple[Setting, ...]
    model_sha256: str | None = None  # of the model file it was measured with (None: a profile from before it was kept)
    fps: float = 10.0  # the frame rate of its H.264 streams

    def cheapest(self, floor: float = DEFAULT_F1_FLOOR) -> Setting | None:
        """The JPEG setting with the fewest bytes whose F1 is at least `floor` (None when none reaches it)."""
        good = [s for s in self.settings if s.f1 >= floor and s.codec == "jpeg"]
        return min(good, key=lambda s: (s.bytes_per_frame, -s.f1)) if good else None

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1) + "\n"

    @classmethod
    def from_json(cls, text: str) -> AccuracyProfile:
        """A profile from its JSON; ValueError saying what is wrong."""
        try:
            data = json.loads(text)
            rows = data["settings"]
            if not isinstance(rows, list) or not 0 < len(rows) <= MAX_SETTINGS:
                raise ValueError(f"settings must be a list of 1 to {MAX_SETTINGS} rows")
            settings = tuple(_setting(row) for row in rows)
            width, height = (int(v) for v in data["source_size"])
            digest = data.get("model_sha256")
            if digest is not None and not (isinstance(digest, str) and re.fullmatch(r"[0-9a-f]{64}", digest)):
                raise ValueError("model_sha256 must be 64 lowercase hexadecimal characters")
            return cls(
                str(data["model"]),
                str(data["source"]),
                (width, height),
                int(data["frames"]),
                str(data["measured"]),
                settings,
                digest,
                float(data.get("fps", 10.0)),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"not an accuracy profile: {exc}") from None


def _fraction(value: Any) -> float | None:
    return None if value is None else float(value)


def _setting(row: Any) -> Setting:
    long_side = row["long_side"]
    codec = row.get("codec", "jpeg")
    bitrate = row.get("bitrate_kbps")
    if codec not in ("jpeg", "h264") or (codec == "h264") != (bitrate is not None):
        raise ValueError(f"a setting's codec is jpeg, or h264 with a bitrate: {row}")
    setting = Setting(
        None if long_side is None else int(long_side),
        int(row["quality"]),
        float(row["f1"]),
        float(row["bytes_per_frame"]),
        _fraction(row.get("mask_iou")),
        _fraction(row.get("oks")),
        codec,
        None if bitrate is None else int(bitrate),
    )
    fractions = [v for v in (setting.f1, setting.mask_iou, setting.oks) if v is not None]
    quality_ok = 1 <= setting.quality <= 100 if codec == "jpeg" else setting.bitrate_kbps > 0  # type: ignore[operator]
    if not (quality_ok and all(0 <= v <= 1 for v in fractions) and setting.bytes_per_frame > 0):
        raise ValueError(f"a setting out of range: {row}")
    if setting.long_side is not None and setting.long_side < 16:
        raise ValueError(f"a long side under 16 pixels: {row}")
    return setting


def load_profile(model: str) -> AccuracyProfile | None:
    """The shipped profile of `model` (its processor name), None when there is none."""
    path = PROFILES / f"{Path(model).name}.json"
    return AccuracyProfile.from_json(path.read_text()) if path.is_file() else None
