"""Run a benchmark's quick mode as a user would (`python -m bench.NAME`) and find the run folder it wrote."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.support.paths import ROOT


def run_bench(
    name: str, out: Path, model: Path | None, video: Path, *args: str, timeout_s: float = 240
) -> tuple[Path, str]:
    """`python -m bench.NAME --quick ARGS --model M --video V --out OUT` (no `--model` for None); asserts it
    succeeded and returns the one run folder under `out` and what it printed."""
    done = subprocess.run(
        [sys.executable, "-m", f"bench.{name}", "--quick", *args]
        + (["--model", str(model)] if model else [])
        + ["--video", str(video), "--out", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    (run,) = out.iterdir()
    return run, done.stdout
