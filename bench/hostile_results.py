"""bench/hostile.py's result attacks (issue 45, rows 12 to 14): a processor whose results are hostile for the
attacker's frames (336 pixels wide) and plain for everyone else's (the good robot's, 320 wide), served by the netapp
under test (`netapp serve --processor bench.hostile_results:HostileResults`). The attacker sends frames with
`?wait=true` and draws every result it gets as `netapp stream --save` does; what the netapp refused is read from
its /metrics."""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import requests

from netapp.client.draw import draw_result
from netapp.client.netapp_client import Result
from netapp.results import MAX_MASK_SIDE
from netapp.sdk.processor import Processor
from tests.support.images import make_jpeg

ATTACK_WIDTH = 336
GOOD = {"bbox": [10.0, 20.0, 100.0, 200.0], "score": 0.9, "class": 0, "class_name": "person"}


def nested(depth: int) -> dict:
    value: dict = {}
    for _ in range(depth):
        value = {"a": value}
    return value


def huge_rle() -> dict:
    """A valid compressed RLE of 16384x16384 (the wire's largest) holding a 64x64 square."""
    from pycocotools import mask as coco_mask

    side, inside = MAX_MASK_SIDE, 64
    counts = [0, inside] + [side - inside, inside] * (inside - 1)
    counts.append(side * side - sum(counts))
    encoded = coco_mask.frPyObjects({"size": [side, side], "counts": counts}, side, side)
    return {"size": [side, side], "counts": encoded["counts"].decode("ascii")}


def hostile(kind: str) -> dict[str, Any]:
    if kind == "deep":
        return {"detections": [GOOD], "deep": nested(300)}
    if kind == "not-finite":
        bad = [float("nan"), float("inf"), 1e308, "1"]
        detections = [{**GOOD, "bbox": [v, 1.0, 2.0, 3.0]} for v in bad]
        return {"detections": [*detections, {**GOOD, "class_name": "n" * 10_000_000}, GOOD]}
    if kind == "too-big":
        return {"detections": [GOOD], "note": "x" * 10_000_000}
    rle = huge_rle()
    return {"detections": [{**GOOD, "class": k % 80, "mask": {"rle": rle}} for k in range(300)]}


KINDS = ("deep", "not-finite", "too-big", "huge-masks")


class HostileResults(Processor):
    """Plain results for every frame but the attacker's (336 wide), whose result is hostile of the kind its height
    names: KINDS[height % 4] (240 + k)."""

    name = "hostile-results"

    def process(self, batch: Any) -> list[dict[str, Any]]:
        out = []
        for image in batch:
            height, width = image.shape[:2]
            out.append(hostile(KINDS[(height - 240) % 4]) if width == ATTACK_WIDTH else {"detections": [GOOD]})
        return out


def counted(url: str) -> dict[str, float]:
    text = requests.get(f"{url}/metrics", timeout=10).text
    found = re.findall(r"^netapp_(?:frames_rejected|result_fields_refused)_total\{([^}]*)\} (\S+)$", text, re.M)
    totals: dict[str, float] = {}
    for labels, value in found:
        reason = re.search(r'reason="(\w+)"', labels)
        if reason:
            totals[reason.group(1)] = totals.get(reason.group(1), 0.0) + float(value)
    return totals


def results_attack(kind: str, frames: int = 20) -> Callable[[Any], tuple[int, int, str]]:
    def attack(t: Any) -> tuple[int, int, str]:
        before = counted(t.url)
        session = requests.post(f"{t.url}/register", json={}, timeout=10).json()["session_id"]
        jpeg = make_jpeg(ATTACK_WIDTH, 240 + KINDS.index(kind))
        frame = np.zeros((240 + KINDS.index(kind), ATTACK_WIDTH, 3), np.uint8)
        statuses: dict[int, int] = {}
        lost, drawing = 0, 0.0
        for _ in range(frames):
            try:
                response = requests.post(
                    f"{t.url}/send_image",
                    params={"wait": "true"},
                    data=jpeg,
                    headers={"X-Session-Id": session, "Content-Type": "image/jpeg"},
                    timeout=30,
                )
                status = response.status_code
            except requests.RequestException:
                status = 0
            statuses[status] = statuses.get(status, 0) + 1
            lost += status == 0
            if status == 200:  # what the robot's --save would draw
                start = time.perf_counter()
                draw_result(frame, Result(1, response.json().get("detections", []), 10.0, response.json(), None))
                drawing = max(drawing, time.perf_counter() - start)
        now = counted(t.url)
        reasons = {k: int(v - before.get(k, 0.0)) for k, v in now.items() if v - before.get(k, 0.0)}
        return frames, lost, f"statuses {statuses}; counted {reasons}; longest drawing {drawing * 1000:.0f} ms"

    return attack


RESULT_ATTACKS: dict[str, Callable[[Any], tuple[int, int, str]]] = {
    f"results-{kind}": results_attack(kind) for kind in KINDS
}
