"""The numeric steps every family shares, pure numpy (and OpenCV's NMS): best class per candidate, NMS and rotated
NMS, oriented boxes, instance masks from prototypes, keypoints. Input pixels in, frame pixels out."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from netapp.models.preprocess import Placement

MAX_NMS = 30000  # candidates NMS looks at, best first (Ultralytics' max_nms)
CLASS_OFFSET = 7680.0  # shifts each class's boxes apart so one NMS pass is per class (Ultralytics' max_wh)


def xywh_to_xyxy(xywh: np.ndarray) -> np.ndarray:
    half = xywh[:, 2:4] / 2
    return np.concatenate((xywh[:, :2] - half, xywh[:, :2] + half), axis=1)


def best_class(class_scores: np.ndarray, conf: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows of C x N class scores (channels first, as the YOLO exports lay them out) over `conf`: (indices of the
    kept anchors, their best score, their best class). Only the kept anchors pay for the argmax."""
    best = class_scores.max(axis=0)
    keep = np.flatnonzero(best > conf)
    class_ids = class_scores[:, keep].argmax(axis=0) if len(keep) else np.zeros(0, np.int64)
    return keep, best[keep].astype(np.float32), class_ids


def best_first(scores: np.ndarray) -> np.ndarray:
    """Indices by descending score; equal scores latest first, as torch's descending sort leaves them (so that
    of two boxes with one score, the one Ultralytics keeps is kept)."""
    return np.argsort(scores, kind="stable")[::-1]


def nms(boxes_xyxy: np.ndarray, scores: np.ndarray, class_ids: np.ndarray, iou: float, max_det: int) -> np.ndarray:
    """Indices kept by per-class greedy NMS (torchvision's, as Ultralytics runs it), best score first, at most
    `max_det`. OpenCV's NMS does the work; it is given the candidates already in torch's order, which its stable
    sort keeps for equal scores."""
    if len(scores) == 0:
        return np.zeros(0, np.int64)
    order = best_first(scores)[:MAX_NMS]
    b = boxes_xyxy[order].astype(np.float64)
    xywh = np.concatenate((b[:, :2], b[:, 2:] - b[:, :2]), axis=1)
    keep = cv2.dnn.NMSBoxesBatched(
        xywh.tolist(), scores[order].tolist(), class_ids[order].astype(np.int32).tolist(), 0.0, iou, top_k=0
    )
    keep = np.sort(np.asarray(keep, np.int64).reshape(-1))[:max_det]  # positions in `order`: best first
    return order[keep]


# --- oriented boxes ----------------------------------------------------------------------------------------------


def _covariance(rboxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    a, b = rboxes[:, 2] ** 2 / 12, rboxes[:, 3] ** 2 / 12
    cos, sin = np.cos(rboxes[:, 4]), np.sin(rboxes[:, 4])
    return a * cos**2 + b * sin**2, a * sin**2 + b * cos**2, (a - b) * cos * sin


def probiou(first: np.ndarray, second: np.ndarray, eps: float = 1e-7) -> np.ndarray:
    """M x N overlap of oriented boxes (cx, cy, w, h, angle) as Gaussian distributions (ProbIoU, Ultralytics')."""
    a1, b1, c1 = (v[:, None] for v in _covariance(first))
    a2, b2, c2 = (v[None, :] for v in _covariance(second))
    x1, y1 = first[:, 0:1], first[:, 1:2]
    x2, y2 = second[None, :, 0], second[None, :, 1]
    denom = (a1 + a2) * (b1 + b2) - (c1 + c2) ** 2 + eps
    t1 = ((a1 + a2) * (y1 - y2) ** 2 + (b1 + b2) * (x1 - x2) ** 2) / denom * 0.25
    t2 = ((c1 + c2) * (x2 - x1) * (y1 - y2)) / denom * 0.5
    det = np.clip(a1 * b1 - c1**2, 0, None) * np.clip(a2 * b2 - c2**2, 0, None)
    t3 = np.log(denom / (4 * np.sqrt(det) + eps) + eps) * 0.5
    bd = np.clip(t1 + t2 + t3, eps, 100.0)
    return 1 - np.sqrt(1.0 - np.exp(-bd) + eps)


def rotated_nms(
    rboxes: np.ndarray, scores: np.ndarray, class_ids: np.ndarray, iou: float, max_det: int, block: int = 512
) -> np.ndarray:
    """Indices kept by per-class rotated NMS, best first: a box goes when any better box overlaps it by `iou` or
    more (Ultralytics' fast NMS over ProbIoU), worked out a block at a time until `max_det` are kept."""
    order = best_first(scores)[:MAX_NMS]
    boxes = rboxes[order].astype(np.float64)
    boxes[:, :2] += class_ids[order, None] * CLASS_OFFSET
    kept: list[int] = []
    for start in range(0, len(boxes), block):
        chunk = boxes[start : start + block]
        overlaps = probiou(boxes[: start + len(chunk)], chunk)  # every better box against this block
        overlaps[np.arange(start, start + len(chunk))[None, :] <= np.arange(start + len(chunk))[:, None]] = 0
        kept.extend(start + np.flatnonzero((overlaps >= iou).sum(axis=0) == 0))
        if len(kept) >= max_det:
            break
    return order[np.asarray(kept[:max_det], np.int64)]


def rbox_corners(rboxes: np.ndarray) -> np.ndarray:
    """N x 4 x 2 corners of oriented boxes (cx, cy, w, h, angle)."""
    cos, sin = np.cos(rboxes[:, 4]), np.sin(rboxes[:, 4])
    vw = np.stack((rboxes[:, 2] / 2 * cos, rboxes[:, 2] / 2 * sin), axis=1)
    vh = np.stack((-rboxes[:, 3] / 2 * sin, rboxes[:, 3] / 2 * cos), axis=1)
    c = rboxes[:, :2]
    return np.stack((c + vw + vh, c + vw - vh, c - vw - vh, c - vw + vh), axis=1)


def rboxes_to_frame(rboxes: np.ndarray, placement: Placement) -> np.ndarray:
    """Oriented boxes in input pixels -> frame pixels (centre moved, sides scaled; not clipped, as Ultralytics)."""
    out = rboxes.astype(np.float32, copy=True)
    out[:, :2] = placement.points_to_frame(rboxes[:, :2], clip=False)
    out[:, 2] /= placement.scale_x  # a letterbox scales both axes alike; a stretch's oriented box is approximate
    out[:, 3] /= placement.scale_y
    return out


# --- masks -------------------------------------------------------------------------------------------------------


def mask_in_box(
    coefficients: np.ndarray, protos: np.ndarray, box: np.ndarray, input_hw: tuple[int, int]
) -> tuple[np.ndarray, int, int]:
    """One instance's mask over its box, at the model's input resolution: (boolean mask, x0, y0 of its top-left
    pixel in the input). Only the box's part of the prototypes is mixed (coefficients @ prototypes) and upsampled,
    bilinearly; a pixel is in where the logit is over 0 and it lies in the box, as in Ultralytics' process_mask."""
    channels, ph, pw = protos.shape
    in_h, in_w = input_hw
    # the pixels whose index is in [x1, x2) and [y1, y2), Ultralytics' crop: no per-pixel test needed
    x0, y0 = max(int(math.ceil(box[0])), 0), max(int(math.ceil(box[1])), 0)
    x1, y1 = min(int(math.ceil(box[2])), in_w), min(int(math.ceil(box[3])), in_h)
    if x1 <= x0 or y1 <= y0:
        return np.zeros((0, 0), bool), x0, y0
    # input pixel centre (x + 0.5) -> prototype pixels (their centres at i + 0.5)
    kx, ky = pw / in_w, ph / in_h
    bx, by = (x0 + 0.5) * kx - 0.5, (y0 + 0.5) * ky - 0.5
    # the prototype window that sampling the box touches (one pixel of margin for the bilinear neighbours)
    px0, py0 = max(int(math.floor(bx)) - 1, 0), max(int(math.floor(by)) - 1, 0)
    px1 = min(int(math.ceil(bx + kx * (x1 - x0))) + 2, pw)
    py1 = min(int(math.ceil(by + ky * (y1 - y0))) + 2, ph)
    window = protos[:, py0:py1, px0:px1].reshape(channels, -1)
    logits = (coefficients.astype(np.float32) @ window).reshape(py1 - py0, px1 - px0)
    warp = np.float32([[kx, 0, bx - px0], [0, ky, by - py0]])
    sampled = cv2.warpAffine(
        logits, warp, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE
    )
    return sampled > 0, x0, y0


def mask_to_frame(mask: np.ndarray, x0: int, y0: int, placement: Placement) -> tuple[np.ndarray, int, int]:
    """A mask in input pixels (its top-left at x0, y0) resampled to the frame's pixels, bilinearly, in where over
    one half (Ultralytics' scale_masks): (boolean mask, fx0, fy0 of its top-left pixel in the frame)."""
    h, w = mask.shape
    fx0 = max(int(math.floor((x0 - placement.pad_x) / placement.scale_x)), 0)
    fy0 = max(int(math.floor((y0 - placement.pad_y) / placement.scale_y)), 0)
    fx1 = min(int(math.ceil((x0 + w - placement.pad_x) / placement.scale_x)), placement.width)
    fy1 = min(int(math.ceil((y0 + h - placement.pad_y) / placement.scale_y)), placement.height)
    if fx1 <= fx0 or fy1 <= fy0 or not h or not w:
        return np.zeros((0, 0), bool), fx0, fy0
    # frame pixel centre (u + 0.5) -> input pixels -> this mask's pixel index
    sx, sy = placement.scale_x, placement.scale_y
    warp = np.float32(
        [
            [sx, 0, (fx0 + 0.5) * sx + placement.pad_x - 0.5 - x0],
            [0, sy, (fy0 + 0.5) * sy + placement.pad_y - 0.5 - y0],
        ]
    )
    sampled = cv2.warpAffine(  # in bytes (0 or 255): a third of float32's time, the same half-way cut
        mask.view(np.uint8) * np.uint8(255),
        warp,
        (fx1 - fx0, fy1 - fy0),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT,
    )
    return sampled > 127, fx0, fy0


def region_rle(mask: np.ndarray, x0: int, y0: int, height: int, width: int) -> dict[str, Any]:
    """COCO's compressed RLE of a height x width frame that is empty but for `mask` at (x0, y0): the runs are counted
    over the mask's columns only (column-major, as COCO counts), never over a frame-sized array."""
    from pycocotools import mask as coco_mask

    h, w = mask.shape
    columns = np.zeros((w, height), bool)  # the frame's columns x0 .. x0 + w, each a whole column
    columns[:, y0 : y0 + h] = mask.T
    flat = columns.reshape(-1)
    changes = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    edges = np.concatenate(([0], changes, [flat.size]))
    runs = np.diff(edges)
    counts = runs.tolist()
    if flat[0]:  # COCO's counts start with a run of zeros
        counts.insert(0, 0)
    counts[0] += x0 * height  # the empty columns before
    after = (width - x0 - w) * height  # and after: they join the last run when it is zeros (an odd count of runs)
    if len(counts) % 2 == 1:
        counts[-1] += after
    elif after:
        counts.append(after)
    height, width = int(height), int(width)
    encoded = coco_mask.frPyObjects({"size": [height, width], "counts": counts}, height, width)
    return {"size": [height, width], "counts": encoded["counts"].decode("ascii")}


def polygons_to_frame(polygons: list[list[float]], placement: Placement) -> list[list[float]]:
    """Flat polygons of pixel centres in input pixels -> the frame's (centres to centres), rounded to 0.1 px."""
    if not polygons:
        return []
    lengths = np.cumsum([len(p) for p in polygons])[:-1]
    xy = np.asarray([v for p in polygons for v in p], np.float32).reshape(-1, 2) + 0.5
    frame = placement.points_to_frame(xy, clip=False) - 0.5
    np.clip(frame, 0, [placement.width, placement.height], out=frame)
    return [part.tolist() for part in np.split(np.round(frame.reshape(-1), 1), lengths)]


# --- classification ----------------------------------------------------------------------------------------------


def probabilities(values: np.ndarray) -> np.ndarray:
    """Class probabilities: as they are when the graph ends in a softmax (non-negative, summing to 1), else softmax."""
    values = values.astype(np.float64).reshape(-1)
    if values.min(initial=0.0) >= 0 and abs(values.sum() - 1.0) < 1e-3:
        return values
    shifted = np.exp(values - values.max())
    return shifted / shifted.sum()


def top_k(probs: np.ndarray, k: int) -> np.ndarray:
    """Indices of the k best, best first."""
    k = min(k, len(probs))
    part = np.argpartition(-probs, k - 1)[:k] if k < len(probs) else np.arange(len(probs))
    return part[np.argsort(-probs[part], kind="stable")]
