"""bench/picture_costs.py, quick: every picture step of the data path timed on real frames (real libx264 and PyAV,
OpenCV's JPEG), back to back and paced."""

from __future__ import annotations

import re

from tests.support.bench_runs import run_bench


def test_every_step_is_timed_both_ways(tmp_path, media_dir):
    run, stdout = run_bench("picture_costs", tmp_path, None, media_dir / "pedestrians.avi")
    rows = [
        line
        for line in (run / "table.md").read_text().splitlines()
        if line.startswith("| robot") or line.startswith("| netapp") or line.startswith("| direct")
    ]
    assert len(rows) == 6
    for row in rows:  # two positive medians a row
        assert len(re.findall(r"\| [\d,]+ ", row + " ")) == 2 and " 0 |" not in row, row
    assert "H.264 encode 416x312" in stdout  # the size NetAppClient sends for a 416x416 model
