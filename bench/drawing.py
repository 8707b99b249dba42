"""What showing masks and keypoints costs outside the model, on a 1280x720 frame with 20 objects.

    python -m bench.drawing

Per row, the median of `--repeat` runs in ms: the robot's drawing (`netapp.client.draw.draw_result`, what
`netapp stream --save/--show` does per frame) with 20 polygon masks, 20 RLE masks, 20 poses (COCO-17) and 20
oriented boxes; `Result.masks(720, 1280)` for 20 masks of each form; and the netapp's bound on the same results
(`netapp.results.bound_result`, on the event loop per result). The masks are ellipses made into their wire form
as a model's would be (`Mask.from_array`: polygons simplified to at most 1,000 points, or COCO RLE).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable

import numpy as np

from netapp.client.delivery import Result
from netapp.client.draw import draw_result
from netapp.results import Detection, Mask, bound_result, to_wire

WIDTH, HEIGHT, OBJECTS = 1280, 720, 20


def objects(fmt: str) -> list[dict]:
    """20 detections on a 5 x 4 grid, each an ellipse mask (`fmt`), a COCO-17 pose and an oriented box."""
    yy, xx = np.mgrid[:HEIGHT, :WIDTH]
    out = []
    for i in range(OBJECTS):
        cx, cy = (i % 5 + 0.5) * WIDTH / 5, (i // 5 + 0.5) * HEIGHT / 4
        rx, ry = WIDTH / 12, HEIGHT / 10
        mask = ((xx - cx) / rx) ** 2 + ((yy - cy) / ry) ** 2 <= 1
        angles = np.linspace(0, 2 * np.pi, 17, endpoint=False)
        keypoints = np.stack([cx + rx * np.cos(angles), cy + ry * np.sin(angles), np.full(17, 0.9)], axis=1)
        box = (cx - rx, cy - ry, cx + rx, cy + ry)
        rbox = (cx, cy, rx, ry, 0.3)
        out.append(Detection(box, 0.9, i % 80, f"class{i}", Mask.from_array(mask, fmt=fmt), keypoints, rbox))
    return to_wire(out)


def timed(fn: Callable[[], object], repeat: int) -> float:
    fn()  # warm up
    samples = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        samples.append((time.perf_counter() - start) * 1000)
    return statistics.median(samples)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=50)
    args = parser.parse_args()
    frame = np.full((HEIGHT, WIDTH, 3), 90, np.uint8)
    polygons, rle = objects("polygons"), objects("rle")

    def only(detections: list[dict], *keys: str) -> list[dict]:
        return [{k: v for k, v in d.items() if k not in {"mask", "keypoints", "rbox"} or k in keys} for d in detections]

    def result(detections: list[dict]) -> Result:
        return Result(1, detections, 10.0, {"detections": detections})

    rows = [
        ("draw: 20 boxes only", lambda: draw_result(frame, result(only(polygons)))),
        ("draw: 20 polygon masks", lambda: draw_result(frame, result(only(polygons, "mask")))),
        ("draw: 20 RLE masks", lambda: draw_result(frame, result(only(rle, "mask")))),
        ("draw: 20 poses (COCO-17)", lambda: draw_result(frame, result(only(polygons, "keypoints")))),
        ("draw: 20 oriented boxes", lambda: draw_result(frame, result(only(polygons, "rbox")))),
        ("draw: all of it (polygons)", lambda: draw_result(frame, result(polygons))),
        ("Result.masks: 20 polygon masks", lambda: result(polygons).masks(HEIGHT, WIDTH)),
        ("Result.masks: 20 RLE masks", lambda: result(rle).masks(HEIGHT, WIDTH)),
        ("netapp bound: 20 polygon masks + poses", lambda: bound_result({"detections": polygons})),
        ("netapp bound: 20 RLE masks + poses", lambda: bound_result({"detections": rle})),
    ]
    points = sum(len(p) // 2 for d in polygons for p in d["mask"]["polygons"])
    chars = sum(len(d["mask"]["rle"]["counts"]) for d in rle)
    print(f"{WIDTH}x{HEIGHT}, {OBJECTS} objects: {points} polygon points, {chars} RLE characters in all")
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}")
    print(f"{'what':42} {'ms (median)':>12}")
    for name, fn in rows:
        print(f"{name:42} {timed(fn, args.repeat):12.2f}")


if __name__ == "__main__":
    main()
