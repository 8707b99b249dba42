"""The rollout's pure parts: the comparison of two answers, the sampler and its budget, and the verdict."""

from __future__ import annotations

import numpy as np
import pytest

from netapp.models.matching import FrameAgreement
from netapp.results import Mask
from netapp.server.rollout.compare import compare_results
from netapp.server.rollout.shadow import Sampler, ShadowStats
from netapp.server.rollout.verdict import CANARY, PROMOTED, ROLLED_BACK, SHADOW, Evidence, in_canary, judge, p95
from netapp.server.settings import Policy

PERSON = {"bbox": [10, 10, 50, 90], "class": 0, "score": 0.9}
DOG = {"bbox": [60, 20, 100, 60], "class": 16, "score": 0.8}


def evidence(frames=50, agreement=1.0, current=0.02, candidate=0.02, errors=0) -> Evidence:
    return Evidence(frames, min(frames, 50), agreement, current, candidate, errors, "boom" if errors else None)


def test_the_same_answer_agrees_fully_and_a_moved_or_relabelled_box_does_not():
    assert compare_results({"detections": [PERSON, DOG]}, {"detections": [DOG, PERSON]}) == FrameAgreement(2, 2, 2)
    moved = {**PERSON, "bbox": [40, 10, 80, 90]}  # IoU 0.2
    assert compare_results({"detections": [PERSON]}, {"detections": [moved]}).matched == 0
    assert compare_results({"detections": [PERSON]}, {"detections": [{**PERSON, "class": 1}]}).matched == 0
    assert compare_results({"detections": []}, {"detections": []}) == FrameAgreement(0, 0, 0)


def test_masks_are_compared_by_iou_in_the_frame_and_classifiers_by_top_1():
    full = np.zeros((100, 120), bool)
    full[10:90, 10:50] = True
    half = full.copy()
    half[50:90] = False
    a = {**PERSON, "mask": Mask.from_array(full, fmt="rle").to_wire()}
    b = {**PERSON, "mask": Mask.from_array(half).to_wire()}
    result = compare_results({"detections": [a]}, {"detections": [b]}, frame_size=(120, 100))
    assert result.matched == 1 and result.mask_ious[0] == pytest.approx(0.5, abs=0.05)
    top = {"classifications": [{"class": 3, "score": 0.9}]}
    assert compare_results(top, top) == FrameAgreement(1, 1, 1)
    assert compare_results(top, {"classifications": [{"class": 4, "score": 0.9}]}) == FrameAgreement(0, 1, 1)


def test_sampler_takes_its_share_evenly_and_holds_within_its_budget():
    sampler = Sampler(share=0.25, budget=0.1)
    assert [sampler.wants() for _ in range(8)] == [False, False, False, True] * 2
    assert sampler.within_budget()  # the first run measures
    sampler.current_ran(1.0)
    sampler.candidate_ran(0.2)
    assert not sampler.within_budget()  # 0.2 s of candidate against 0.1 allowed
    sampler.current_ran(1.0)
    assert sampler.within_budget()


def test_stats_judge_the_latest_window_only():
    stats = ShadowStats(window=4)
    for _ in range(4):
        stats.compared(FrameAgreement(0, 1, 1), 0.01, 0.01)
    for _ in range(4):
        stats.compared(FrameAgreement(1, 1, 1), 0.01, 0.03)
    seen = stats.evidence()
    assert (seen.phase_frames, seen.window_frames, seen.agreement) == (8, 4, 1.0)
    assert seen.p95_candidate_s == pytest.approx(0.03)
    assert p95([]) is None and p95([float(i) for i in range(1, 101)]) == 95.0


def test_verdict_promotes_after_n_agreeing_frames_and_only_then():
    policy = Policy(promote_after=100, window=50)
    assert judge(SHADOW, evidence(frames=99), policy).phase == SHADOW
    assert judge(SHADOW, evidence(frames=100), policy).phase == PROMOTED
    assert judge(SHADOW, evidence(frames=100), Policy(promote_after=100, canary_share=0.1)).phase == CANARY
    assert judge(CANARY, evidence(frames=100), Policy(promote_after=100, canary_share=0.1)).phase == PROMOTED
    assert judge(PROMOTED, evidence(errors=3), policy).phase == PROMOTED  # final


@pytest.mark.parametrize(
    "seen, words",
    [
        (evidence(agreement=0.9), "agreement (F1) 0.900"),
        (evidence(candidate=0.031), "1.6x slower at p95"),
        (evidence(errors=1), "failed on 1 frame(s): boom"),
    ],
)
def test_verdict_rolls_back_with_the_reason(seen, words):
    verdict = judge(SHADOW, seen, Policy())
    assert verdict.phase == ROLLED_BACK and words in verdict.reason


def test_a_few_frames_are_not_judged_on_agreement_or_speed():
    assert judge(SHADOW, evidence(frames=10, agreement=0.0, candidate=1.0), Policy()).phase == SHADOW


def test_policy_problems_are_one_line_each():
    assert Policy().problem() is None
    assert "max_slowdown" in Policy(max_slowdown=0.5).problem()
    assert "min_agreement" in Policy(min_agreement=2).problem()


def test_a_robot_stays_on_its_side_of_the_canary_and_the_share_holds():
    robots = [f"robot-{i}" for i in range(2000)]
    inside = [r for r in robots if in_canary(r, 0.1)]
    assert 150 < len(inside) < 250
    assert all(in_canary(r, 0.1) for r in inside) and not any(in_canary(r, 0.0) for r in robots)
