"""The accuracy profile of a model: how its detections change as frames get smaller or more compressed, against the
same frames at full size without compression (F1 of boxes matched at IoU >= 0.5, same class; mask IoU and OKS for a
model with masks or keypoints), and what each setting costs in bytes. Writes the profile a robot ships with
(`netapp.accuracy`); `netapp profile MODEL --media M` measures the same for any model
(`netapp.apps.profiling`), and this adds the table and the plot.

    python -m bench.accuracy                                    # YOLOX-Nano on the pedestrian video, 40 frames
    python -m bench.accuracy --model M --video V --write        # the profile for another model, into the package
    python -m bench.accuracy --plot docs/accuracy.png           # F1 against bytes per frame, a line per size

Frames are taken evenly through the video; what a setting does to a frame: `netapp.apps.profiling`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bench.robot import ROBOT_SETTINGS
from netapp.accuracy import PROFILES, AccuracyProfile
from netapp.apps.profiling import make_profile
from netapp.models import Detector, DetectorConfig
from tests.support.paths import SHARED

# What NetAppClient sends without adaptation: the source's size at its default JPEG quality.
TODAY_DEFAULT = (None, ROBOT_SETTINGS.jpeg_quality)


def table(profile: AccuracyProfile) -> str:
    today = next(s for s in profile.settings if (s.long_side, s.quality) == TODAY_DEFAULT)
    picks = {floor: profile.cheapest(floor) for floor in (0.9, 0.95)}
    lines = [
        "| long side | JPEG quality | F1 | KB per frame | fewer bytes than today |",
        "|---|---:|---:|---:|---:|",
    ]
    for s in sorted(profile.settings, key=lambda s: -s.bytes_per_frame):
        marks = [f"cheapest at F1 >= {floor}" for floor, pick in picks.items() if pick == s]
        if s == today:
            marks.append("today's default")
        side = "full" if s.long_side is None else str(s.long_side)
        lines.append(
            f"| {side} | {s.quality} | {s.f1:.3f} | {s.bytes_per_frame / 1000:.1f} | "
            f"{today.bytes_per_frame / s.bytes_per_frame:.1f}x{' (' + ', '.join(marks) + ')' if marks else ''} |"
        )
    return "\n".join(lines)


def plot(profile: AccuracyProfile, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for side in sorted({s.long_side or 10_000 for s in profile.settings}, reverse=True):
        rows = sorted((s for s in profile.settings if (s.long_side or 10_000) == side), key=lambda s: s.bytes_per_frame)
        label = "full size" if side == 10_000 else f"long side {side}"
        ax.plot([s.bytes_per_frame / 1000 for s in rows], [s.f1 for s in rows], marker="o", label=label)
    ax.axhline(0.9, color="grey", linestyle=":", linewidth=1)
    ax.set_xscale("log")
    ax.set_xlabel("KB per frame (JPEG; qualities along each line)")
    ax.set_ylabel("F1 against full quality")
    ax.set_title(f"{profile.model} on {profile.source} ({profile.frames} frames)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> int:
    p = argparse.ArgumentParser(prog="python -m bench.accuracy", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default=str(SHARED / "models" / "yolox_nano.onnx"))
    p.add_argument("--video", default=str(SHARED / "media" / "pedestrians.avi"))
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--sides", default="full,1280,960,640,416,320,256", help="long sides in pixels, or full")
    p.add_argument("--qualities", default="95,85,70,50,35,20")
    p.add_argument("--write", action="store_true", help="write the profile into netapp/profiles/")
    p.add_argument("--plot", help="a PNG of F1 against bytes per frame")
    args = p.parse_args()
    for path in (args.model, args.video):
        if not Path(path).is_file():
            print(f"{path} does not exist: give --model and --video (the defaults are in ../shared)", file=sys.stderr)
            return 2
    sides = [None if s == "full" else int(s) for s in args.sides.split(",")]
    qualities = [int(q) for q in args.qualities.split(",")]
    if (None not in sides) or (85 not in qualities):
        print("--sides needs full and --qualities 85: today's default is the table's baseline", file=sys.stderr)
        return 2
    detector = Detector(DetectorConfig(args.model))
    detector.load()
    profile = make_profile(
        args.model,
        detector.name,
        detector.detect,
        args.video,
        args.frames,
        sides,
        qualities,
        progress=lambda s: print(
            f"  long side {s.long_side or 'full'}, quality {s.quality}: F1 {s.f1:.3f}", file=sys.stderr
        ),
    )
    print(table(profile))
    if args.write:
        path = PROFILES / f"{profile.model}.json"
        path.write_text(profile.to_json())
        print(f"wrote {path}", file=sys.stderr)
    if args.plot:
        plot(profile, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
