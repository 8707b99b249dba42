"""What decoding costs outside the model: from the raw outputs of one frame to the result's detections (NMS, masks,
keypoints, the wire form), for each task, on the frame sizes robots send.

    python -m bench.models                 # make bench-models; about 20 s
    python -m bench.models --repeat 500 --json

The outputs are made up front, laid out as the Ultralytics exports lay them (YOLO11 at 640x640, 80 classes):
detection with 100 candidates over the threshold (goal <= 1 ms), segmentation with 20 masks of people-sized
objects on a 1280x720 frame (goal <= 4 ms, polygons and RLE), pose with 20 people (goal <= 1 ms). Where the shared
exports are present, their real outputs on ped100.jpg are timed too (untrained weights: 50 ragged masks). One
thread, OpenCV on one thread, as the netapp's inference lane runs it. Prints a table of p50/p95 (ms) and the load
average.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from netapp.models.card import ModelCard, Tensor
from netapp.models.families import recognise
from netapp.models.families.base import Family, Signature
from netapp.models.layouts import anchor_count
from netapp.models.metadata import read_metadata
from netapp.models.preprocess import Placement
from netapp.models.tasks import DecodeOptions, finish
from tests.support.paths import SHARED

INPUT = (640, 640)
HD = (1280, 720)
CLASSES = 80
GOALS_MS = {"detect": 1.0, "segment": 4.0, "pose": 1.0}


def card_for(task: str, outputs: list[tuple[int, ...]]) -> tuple[Family, ModelCard]:
    names = str({i: str(i) for i in range(CLASSES)})
    meta = {"task": task, "names": names, "imgsz": str(list(INPUT))}
    if task == "pose":
        meta["kpt_shape"] = "[17, 3]"
    tensors = tuple(Tensor(f"output{i}", shape) for i, shape in enumerate(outputs))
    sig = Signature((Tensor("images", (1, 3, *INPUT)),), tensors, read_metadata(meta), INPUT)
    return recognise(sig)


def letterbox_of(frame_wh: tuple[int, int]) -> Placement:
    ratio = min(INPUT[1] / frame_wh[0], INPUT[0] / frame_wh[1])
    pad_y = round((INPUT[0] - frame_wh[1] * ratio) / 2 - 0.1)
    pad_x = round((INPUT[1] - frame_wh[0] * ratio) / 2 - 0.1)
    return Placement(ratio, ratio, float(pad_x), float(pad_y), *frame_wh)


def objects(rng: np.random.Generator, count: int, placement: Placement) -> np.ndarray:
    """Boxes (cx, cy, w, h, input pixels) of people-sized objects inside the frame's part of the input."""
    w = rng.uniform(30, 120, count)
    h = w * rng.uniform(1.5, 2.5, count)
    top, bottom = placement.pad_y, INPUT[0] - placement.pad_y
    cx = rng.uniform(w / 2, INPUT[1] - w / 2)
    cy = rng.uniform(top + h / 2, np.maximum(top + h / 2 + 1, bottom - h / 2))
    return np.stack((cx, cy, w, h), axis=1).astype(np.float32)


def head_output(
    rng: np.random.Generator, boxes: np.ndarray, extra: int, copies: int = 3
) -> tuple[np.ndarray, np.ndarray]:
    """(4 + 80 + extra, A) rows: each object found by `copies` nearby anchors (NMS has work), the rest under the
    threshold; returns the output and the anchors each object's first copy sits at."""
    anchors = anchor_count(INPUT)
    out = np.zeros((4 + CLASSES + extra, anchors), np.float32)
    out[4 : 4 + CLASSES] = rng.uniform(0, 0.01, (CLASSES, anchors))  # the background, under any threshold
    slots = rng.choice(anchors, len(boxes) * copies, replace=False).reshape(len(boxes), copies)
    for k, (box, anchor_set) in enumerate(zip(boxes, slots, strict=True)):
        cls = k % CLASSES
        for j, anchor in enumerate(anchor_set):
            out[:4, anchor] = box + rng.normal(0, 2, 4)
            out[4 + cls, anchor] = 0.9 - 0.1 * j
    return out, slots[:, 0]


def detection_case(rng: np.random.Generator) -> tuple[str, list[np.ndarray], str, Placement]:
    placement = letterbox_of((640, 480))
    out, _ = head_output(rng, objects(rng, 34, placement), 0)  # 34 objects x 3 = 102 candidates
    return "detect", [out], "100 candidates, 640x480 frame", placement


def segmentation_case(rng: np.random.Generator) -> tuple[str, list[np.ndarray], str, Placement]:
    placement = letterbox_of(HD)
    boxes = objects(rng, 20, placement)
    out, first = head_output(rng, boxes, 32)
    ph, pw = INPUT[0] // 4, INPUT[1] // 4
    protos = np.full((32, ph, pw), -1.0, np.float32)
    ys, xs = np.mgrid[0:ph, 0:pw].astype(np.float32)
    for k, (cx, cy, w, h) in enumerate(boxes):  # each object a soft ellipse in a prototype channel of its own
        c = k % 32
        ellipse = 1 - ((xs - cx / 4) / (w / 8)) ** 2 - ((ys - cy / 4) / (h / 8)) ** 2
        protos[c] = np.maximum(protos[c], 2 * ellipse)
    for k, anchor in enumerate(first):
        coefficients = np.zeros(32, np.float32)
        coefficients[k % 32] = 1.0
        out[4 + CLASSES :, anchor] = coefficients
        for anchor_copy in np.flatnonzero(out[4 + (k % CLASSES)] >= 0.7):
            out[4 + CLASSES :, anchor_copy] = coefficients
    return "segment", [out, protos], "20 masks, 1280x720 frame", placement


def pose_case(rng: np.random.Generator) -> tuple[str, list[np.ndarray], str, Placement]:
    placement = letterbox_of(HD)
    boxes = objects(rng, 20, placement)
    out, _ = head_output(rng, boxes, 51)
    kpts = rng.uniform(0, 640, (51, out.shape[1])).astype(np.float32)
    kpts[2::3] = rng.uniform(0, 1, (17, out.shape[1]))
    out[4 + CLASSES :] = kpts
    return "pose", [out], "20 people (60 candidates), 1280x720 frame", placement


def timed(run: Callable[[], Any], repeat: int) -> tuple[float, float, Any]:
    run()  # warm
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = run()
        times.append((time.perf_counter() - start) * 1e3)
    times.sort()
    return statistics.median(times), times[int(0.95 * (len(times) - 1))], result


def real_case() -> tuple[str, list[np.ndarray], str, Placement, Family, ModelCard] | None:
    """yolo11n-seg's own outputs on ped100.jpg, where the shared exports are present."""
    path = SHARED / "models" / "exports" / "yolo11n-seg.onnx"
    image = SHARED / "media" / "ped100.jpg"
    if not (path.exists() and image.exists()):
        return None
    from netapp.models import Detector, DetectorConfig

    detector = Detector(DetectorConfig(str(path), conf=0.0001, iou=0.7, max_detections=50))
    detector.load()
    prepared = detector.prepare(cv2.imread(str(image)), {})
    outputs = [o[0] for o in detector.session.run(None, prepared.feeds)]
    return (
        "segment",
        outputs,
        "yolo11n-seg export, ped100.jpg (50 ragged masks)",
        prepared.placement,
        *(
            detector.family,
            detector.card,
        ),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=200, help="timed runs of each case (default %(default)s)")
    parser.add_argument("--json", action="store_true", help="the rows as JSON too")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    rng = np.random.default_rng(0)
    rows = []
    cases = [detection_case(rng), segmentation_case(rng), pose_case(rng)]
    for task, outputs, what, placement in cases:
        family, card = card_for(task, [(1, *o.shape) for o in outputs])
        formats = ("polygons", "rle") if task == "segment" else ("-",)
        for fmt in formats:
            options = DecodeOptions(
                conf=0.25, iou=0.7, max_detections=300, mask_format=fmt if fmt != "-" else "polygons"
            )

            def run(family=family, card=card, outputs=outputs, placement=placement, options=options):
                return finish(family.candidates(outputs, card, options.conf), card, placement, options)

            p50, p95, result = timed(run, args.repeat)
            rows.append(
                {"task": task, "case": what, "masks": fmt, "results": len(result["detections"]), "p50_ms": p50,
                 "p95_ms": p95, "goal_ms": GOALS_MS[task]}
            )  # fmt: skip
    real = real_case()
    if real is not None:
        task, outputs, what, placement, family, card = real
        for fmt in ("polygons", "rle"):
            options = DecodeOptions(conf=0.0001, iou=0.7, max_detections=50, mask_format=fmt)
            p50, p95, result = timed(
                lambda o=options: finish(family.candidates(outputs, card, o.conf), card, placement, o),
                max(5, args.repeat // 20),
            )
            rows.append(
                {"task": task, "case": what, "masks": fmt, "results": len(result["detections"]), "p50_ms": p50,
                 "p95_ms": p95, "goal_ms": None}
            )  # fmt: skip
    print("| task | case | masks | results | p50 ms | p95 ms | goal |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        goal = f"<= {r['goal_ms']:g} ms" if r["goal_ms"] else "-"
        print(
            f"| {r['task']} | {r['case']} | {r['masks']} | {r['results']} | {r['p50_ms']:.2f} | {r['p95_ms']:.2f} "
            f"| {goal} |"
        )
    print(f"\nload average: {' '.join(f'{v:.2f}' for v in os.getloadavg())} ({os.cpu_count()} cores)")
    if args.json:
        print(json.dumps(rows))


if __name__ == "__main__":
    main()
