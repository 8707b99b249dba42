"""bench/overhead_profile.py's pure part: a py-spy stack goes to the first stage it matches; waits are idle."""

from __future__ import annotations

from bench.overhead_profile import classify


def stack(*frames: str) -> str:
    return ";".join(frames)


def test_a_stack_goes_to_its_first_stage_and_a_wait_is_idle():
    lane = "run_batch (netapp/server/pipeline/lanes.py:128)"
    assert classify(stack(lane, "process (netapp/models/detector.py:132)")) == "model (onnxruntime + output decoding)"
    assert classify(stack(lane, "_prepare (netapp/server/pipeline/pipeline.py:210)")) == "JPEG decode + letterbox"
    pacing = stack("stream (netapp/apps/streaming.py:140)", "_sleep_until (netapp/apps/streaming.py:154)")
    assert classify(pacing) == "idle"  # time.sleep is C: its caller is the innermost Python frame
    assert classify(stack(lane, "Condition.wait (threading.py:331)")) == "idle"
