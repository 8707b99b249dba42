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
    slowdowns = (candidate / current,) * frames  # each frame timed alike
    return Evidence(frames, min(frames, 50), agreement, current, candidate, errors, "boom" if errors else None, (),
                    slowdowns)  # fmt: skip


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
        (evidence(candidate=0.031), "1.6x slower on the median of 50 frames timed alike (at p95 31.0 ms against"),
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


def test_agreement_0_over_ten_frames_rolls_back_at_once_and_three_frames_are_too_few():
    policy = Policy(promote_after=200, window=50)
    for frames, phase in ((3, SHADOW), (10, ROLLED_BACK)):
        seen = Evidence(frames, frames, 0.0, 0.02, 0.02, frame_agreements=(0.0,) * frames)
        verdict = judge(SHADOW, seen, policy)
        assert verdict.phase == phase, (frames, verdict)
    assert "agreement (F1) 0.000 over 10 frames is below 0.95 beyond doubt" in verdict.reason
    agreeing = Evidence(199, 50, 1.0, 0.02, 0.02, frame_agreements=(1.0,) * 199, slowdowns=(1.0,) * 199)
    assert judge(SHADOW, agreeing, policy).phase == SHADOW  # a good candidate still waits for its 200 frames


def test_a_candidate_slower_on_every_frame_timed_alike_rolls_back_early_and_an_identical_one_never():
    policy = Policy(promote_after=200, window=50)
    slow = Evidence(12, 12, 1.0, 0.02, 0.06, frame_agreements=(1.0,) * 12, slowdowns=(3.0,) * 12)
    verdict = judge(SHADOW, slow, policy)
    assert verdict.phase == ROLLED_BACK and "3.0x slower on the median of 12" in verdict.reason, verdict
    assert "over 1.5x on 12 of them: beyond doubt" in verdict.reason
    noisy = tuple(0.5 + (i % 7) / 5 for i in range(200))  # the same model on a busy machine: 0.5x to 1.7x
    same = Evidence(200, 50, 1.0, 0.02, 0.025, frame_agreements=(1.0,) * 200, slowdowns=noisy)
    assert judge(SHADOW, same, policy).phase == PROMOTED


def test_a_starved_shadow_says_so_with_the_time_to_a_verdict():
    from netapp.server.rollout.pace import budget_note, verdict_in_s
    from netapp.server.settings import Shadowing

    stats, policy = ShadowStats(window=50), Policy(promote_after=200)
    for _ in range(17):
        stats.compared(FrameAgreement(1, 1, 1), 0.02, 0.1)
    assert budget_note(stats, policy, Shadowing(), 226.0) is None  # nothing skipped
    for _ in range(40):
        stats.skip("budget")
    assert verdict_in_s(stats, policy, 226.0) == pytest.approx(183 / (17 / 226))
    note = budget_note(stats, policy, Shadowing(), 226.0)
    assert note == (
        "the shadow budget (0.1 of the current model's time) skipped 40 of 57 sampled frames: 17 of 200 compared in "
        "4 min, a verdict in about 41 min at this pace unless the evidence decides sooner; a larger --shadow-budget "
        "(shadowBudget) decides sooner"
    )


def test_a_refused_judging_value_is_named_as_the_user_wrote_it():
    from netapp.server.rollout.options import in_flags

    problem = Policy(min_agreement=2).problem()
    assert in_flags(problem) == "--min-agreement must be between 0 and 1"
    from netapp.server.settings import Shadowing

    assert in_flags(Shadowing(sample=0).problem()).startswith("--shadow-sample must be above 0")


def test_rollout_status_prints_the_budget_note():
    from netapp.apps.rollout import describe

    shown = describe({"phase": "shadow", "note": "the shadow budget (0.1 of ...) skipped 40 of 57 sampled frames"})
    assert "note:       the shadow budget (0.1 of ...) skipped 40 of 57 sampled frames" in shown.splitlines()
