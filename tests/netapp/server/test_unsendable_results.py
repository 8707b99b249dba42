"""A result that cannot leave (issue 45, rows 12 and 14): a processor's output nested past JSON's depth, or over
`MAX_RESULT_BYTES`, becomes an error event to its robot, counted on /metrics, and the robot's in-flight slot is free
again; boxes and scores that are not finite numbers, and class names past their bound, never leave."""

from __future__ import annotations

import re
from collections import Counter

import requests

from netapp.results import MAX_NAME_CHARS, MAX_RESULT_BYTES
from netapp.sdk.processor import Processor
from tests.support.raw_frames_robot import RawFramesRobot

GOOD = {"bbox": [1.0, 2.0, 3.0, 4.0], "score": 0.5, "class": 0, "class_name": "person"}


def nested(depth: int) -> dict:
    value: dict = {}
    for _ in range(depth):
        value = {"a": value}
    return value


class Hostile(Processor):
    """Frame k's result: by turns nested 300 deep, 5 MB of class name in an extra field, and hostile boxes."""

    name = "hostile"

    def __init__(self) -> None:
        self.count = 0

    def process(self, batch):
        out = []
        for _ in batch:
            kind = self.count % 3
            self.count += 1
            if kind == 0:
                out.append({"detections": [GOOD], "deep": nested(300)})
            elif kind == 1:
                out.append({"detections": [GOOD], "note": "x" * (MAX_RESULT_BYTES + 1)})
            else:
                bad = [
                    {**GOOD, "bbox": [float("nan"), 1.0, 2.0, 3.0]},
                    {**GOOD, "bbox": [float("inf"), 1.0, 2.0, 3.0]},
                    {**GOOD, "bbox": ["1", "2", "3", "4"]},
                    {**GOOD, "score": float("nan")},
                    {**GOOD, "class_name": "n" * 10_000_000},
                ]
                out.append({"detections": [*bad, GOOD]})
        return out


def rejected_on_metrics(url: str) -> dict[str, float]:
    text = requests.get(f"{url}/metrics", timeout=5).text
    found = re.findall(r'^netapp_frames_rejected_total\{reason="(\w+)",transport="(\w+)"\} (\S+)$', text, re.M)
    found += [
        (r, t, v)
        for t, r, v in re.findall(
            r'^netapp_frames_rejected_total\{transport="(\w+)",reason="(\w+)"\} (\S+)$', text, re.M
        )
    ]
    return {reason: float(value) for reason, _, value in found}


def test_results_that_cannot_leave_are_errors_to_the_robot_and_free_its_slot(serve):
    server = serve(Hostile())
    robot = RawFramesRobot(server.url)
    try:
        robot.init()
        for round_ in range(2):  # the slot is free after each error: the next frames are answered too
            robot.frame(10 * round_ + 1)
            assert robot.next("error")["reason"] == "result_unencodable"
            robot.frame(10 * round_ + 2)
            assert robot.next("error")["reason"] == "result_too_big"
            robot.frame(10 * round_ + 3)
            detections = robot.next("results")["detections"]
            assert detections[:-1] == [{**GOOD, "class_name": "n" * MAX_NAME_CHARS}] and detections[-1] == GOOD
        rejected = rejected_on_metrics(server.url)
        assert rejected["result_unencodable"] == 2 and rejected["result_too_big"] == 2
        text = requests.get(f"{server.url}/metrics", timeout=5).text
        assert re.search(r'netapp_result_fields_refused_total\{reason="bbox_malformed"\} 6', text)
        assert re.search(r'netapp_result_fields_refused_total\{reason="score_malformed"\} 2', text)
    finally:
        robot.close()


class Dropping(Processor):
    """A processor that left two detections out of each result (as the model processor counts them)."""

    name = "dropping"

    def __init__(self) -> None:
        self.dropped: Counter[str] = Counter()

    def process(self, batch):
        self.dropped["detection_failed"] += 2 * len(batch)
        return [{"detections": [GOOD]} for _ in batch]


def test_detections_a_processor_dropped_are_counted_on_metrics(serve):
    server = serve(Dropping())
    robot = RawFramesRobot(server.url)
    try:
        robot.init()
        for k in range(3):
            robot.frame(k + 1)
            assert robot.next("results")["detections"] == [GOOD]
        text = requests.get(f"{server.url}/metrics", timeout=5).text
        assert re.search(r'netapp_result_fields_refused_total\{reason="detection_failed"\} 6', text)
    finally:
        robot.close()
