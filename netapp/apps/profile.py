"""`netapp profile MODEL`: measure a model's accuracy profile (netapp.apps.profiling) and write it as JSON.

    netapp profile model.onnx --media video.mp4 --out model.json

The profile records the model file's SHA-256: a netapp names only a profile made for its own model.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

DEFAULT_SIDES = "full,1280,960,640,416,320,256"
DEFAULT_QUALITIES = "95,85,70,50,35,20"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", help="the ONNX model file")
    parser.add_argument("--media", required=True, help="what to measure on: a video, an image or a folder of images")
    parser.add_argument("--out", help="where to write the profile (default: MODEL_NAME.json here)")
    parser.add_argument("--frames", type=int, default=40, help="frames taken evenly through the video (default 40)")
    parser.add_argument("--sides", default=DEFAULT_SIDES, help=f"long sides in pixels, or full ({DEFAULT_SIDES})")
    parser.add_argument("--qualities", default=DEFAULT_QUALITIES, help=f"JPEG qualities ({DEFAULT_QUALITIES})")
    parser.add_argument("--conf", type=float, default=0.3, help="the score threshold the netapp serves with (0.3)")


def _numbers(text: str, name: str, allow_full: bool = False) -> list[int | None]:
    try:
        values = [None if allow_full and v.strip() == "full" else int(v) for v in text.split(",")]
    except ValueError:
        raise SystemExit(f"netapp profile: --{name} takes numbers separated by commas, got {text!r}") from None
    if not values or any(v is not None and not 1 <= v <= 100_000 for v in values):
        raise SystemExit(f"netapp profile: --{name} out of range: {text!r}")
    return values


def run(args: argparse.Namespace) -> int:
    from netapp.apps.profiling import make_profile
    from netapp.models import Detector, DetectorConfig

    sides = _numbers(args.sides, "sides", allow_full=True)
    qualities = _numbers(args.qualities, "qualities")
    if any(q is not None and q > 100 for q in qualities):
        raise SystemExit("netapp profile: a JPEG quality is 1 to 100")
    for path, what in ((args.model, "model"), (args.media, "--media")):
        if not Path(path).exists():
            print(f"netapp profile: {what} {path} does not exist", file=sys.stderr)
            return 2
    detector = Detector(DetectorConfig(args.model, conf=args.conf))
    try:
        detector.load()
        profile = make_profile(
            args.model,
            detector.name,
            detector.detect,
            args.media,
            frames=args.frames,
            sides=sides,
            qualities=qualities,
            progress=lambda s: print(f"  {s.describe()}", file=sys.stderr),
        )
    except ValueError as exc:
        print(f"netapp profile: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out or f"{detector.name}.json")
    out.write_text(profile.to_json())
    print(f"wrote {out} ({len(profile.settings)} settings, model sha256 {profile.model_sha256[:12]}...)")
    return 0
