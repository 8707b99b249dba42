"""Matching detections by place: overlap, greedy pairs, and the agreement F1 the accuracy profile is made of."""

from __future__ import annotations

import pytest

from netapp.models.matching import agreement_f1, box_iou, greedy_matches, same_class


def det(x1: float, y1: float, x2: float, y2: float, cls: int = 0) -> dict:
    return {"bbox": [x1, y1, x2, y2], "class": cls}


def test_box_iou() -> None:
    assert box_iou([0, 0, 10, 10], [0, 0, 10, 10]) == 1.0
    assert box_iou([0, 0, 10, 10], [5, 0, 15, 10]) == pytest.approx(50 / 150)
    assert box_iou([0, 0, 10, 10], [10, 10, 20, 20]) == 0.0  # touching corners do not overlap


def test_greedy_matches_pair_the_best_overlap_first_and_each_box_once() -> None:
    first = [det(0, 0, 10, 10), det(100, 100, 110, 110)]
    second = [det(1, 0, 11, 10), det(0, 0, 10, 10), det(200, 200, 210, 210)]
    assert greedy_matches(first, second, 0.5) == [(0, 1)]  # (0, 0) overlaps less and box 0 is taken by then
    assert greedy_matches(first, [det(0, 0, 10, 10, cls=3)], 0.5, same_class) == []


def test_agreement_f1() -> None:
    ref = [[det(0, 0, 10, 10), det(20, 20, 30, 30)], []]
    assert agreement_f1(ref, ref) == 1.0
    assert agreement_f1([[], []], [[], []]) == 1.0  # nothing found by either: they agree
    assert agreement_f1(ref, [[det(0, 0, 10, 10)], []]) == pytest.approx(2 / 3)  # one missed
    assert agreement_f1(ref, [[det(0, 0, 10, 10), det(20, 20, 30, 30, cls=1)], []]) == pytest.approx(0.5)
    assert agreement_f1(ref, [[], [det(0, 0, 5, 5)]]) == 0.0
    with pytest.raises(ValueError):  # frames must line up
        agreement_f1(ref, [[]])
