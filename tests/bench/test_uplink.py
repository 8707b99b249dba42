"""bench/uplink.py: its pure parts, and a very short row end to end (a real netapp, the link emulator, two
`netapp stream` robots: --adapt auto and off)."""

from __future__ import annotations

import json

from bench.uplink import SWING_RANGE_MBIT, recovery_s, swing_trace
from tests.support.bench_runs import run_bench


def test_the_swing_trace_swings_tenfold_and_is_the_same_every_run():
    trace = swing_trace(60)
    rates = [c.up_mbit for c in trace]
    assert trace == swing_trace(60) and len(trace) == 30
    assert all(SWING_RANGE_MBIT[0] <= r <= SWING_RANGE_MBIT[1] for r in rates)
    assert max(rates) / min(rates) > 5
    assert any(max(a, b) / min(a, b) > 3 for a, b in zip(rates, rates[1:], strict=False))


def test_recovery_is_the_end_of_the_last_window_over_the_budget_after_each_step():
    records = [{"t": t / 10, "latency_ms": 400.0 if 20 <= t < 25 else 80.0} for t in range(400)]
    assert recovery_s(records, (20.0, 30.0), 40.0, 150.0) == [0.0, 0.0]  # over the budget before the steps only
    records = [{"t": t / 10, "latency_ms": 400.0 if 200 <= t < 215 else 80.0} for t in range(400)]
    assert recovery_s(records, (20.0, 30.0), 40.0, 150.0) == [1.5, 0.0]


def test_a_quick_row_runs_side_by_side(tmp_path, real_model_path, media_dir):
    video = media_dir / "pedestrians.avi"
    run, stdout = run_bench("uplink", tmp_path, real_model_path, video, "--rows", "4", "--link-mode", "userspace")
    figures = {f["mode"]: f for f in json.loads((run / "runs.json").read_text())["figures"]}
    assert set(figures) == {"auto", "off"}
    assert all(f["results_per_s"] > 0 and f["f1"] is not None for f in figures.values())
    assert figures["auto"]["settings"] is not None and figures["off"]["settings"] is None
    assert "uplink 4 Mbit/s | auto" in stdout and (run / "uplink.png").is_file()
