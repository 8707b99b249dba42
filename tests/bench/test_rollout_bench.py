"""bench/rollout.py, quick: a real netapp with and without a shadowed candidate, robots streaming; the table
comes out, and the shadow compared frames while the baseline compared none."""

from __future__ import annotations

import subprocess
import sys

from tests.support.paths import ROOT


def test_a_quick_run_prints_the_table(real_model_path, media_dir):
    out = subprocess.run(
        [sys.executable, "-m", "bench.rollout", "--quick", "--model", str(real_model_path), "--image",
         str(media_dir / "ped100.jpg")],
        cwd=ROOT, capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    rows = {line.split("|")[1].strip(): line.split("|") for line in out.stdout.splitlines() if line.startswith("| ")}
    assert float(rows["none"][2]) > 0 and float(rows["shadow"][2]) > 0
    assert float(rows["none"][5]) == 0 and float(rows["shadow"][5]) > 0  # frames compared/s
