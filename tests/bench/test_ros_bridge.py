"""bench/ros_bridge.py: a few frames of each kind through `netapp stream`'s path and through `netapp ros2` over
real DDS (a real netapp, the bridge as its own process), every frame answered both ways."""

from __future__ import annotations

import json

import pytest

from tests.support.bench_runs import run_bench

pytest.importorskip("cyclonedds")


def test_a_quick_run_answers_both_ways(tmp_path, real_model_path, media_dir):
    video = media_dir / "pedestrians.avi"
    run, stdout = run_bench("ros_bridge", tmp_path, real_model_path, video, "--sizes", "640x480", "--domain", "41")
    rows = {r["kind"]: r for r in json.loads((run / "runs.json").read_text())}
    assert set(rows) == {"compressed", "raw"}
    for row in rows.values():
        assert row["stream_answered"] >= 8 and row["bridge_answered"] >= 8  # of 10: best effort may lose one
        assert row["added_ms"] is not None and row["bridge_summary"]["published"] >= row["bridge_answered"]
    assert all(set(r["decode_ms"]) == {"bytes", "list"} for r in rows.values())
    assert "| Image (bgr8) 640x480 |" in stdout
