"""bench/tracing.py, quick: each mode's row, with the spans each mode should export (none off, 8 a frame at 100 %),
through a real netapp, a real robot and an OTLP receiver of its own."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.support.paths import ROOT

pytest.importorskip("opentelemetry.sdk", reason="the tracing extra is absent: pip install 'netapp-toolkit[tracing]'")


def test_the_table_has_every_mode_and_the_spans_each_exports():
    done = subprocess.run(
        [sys.executable, "-m", "bench.tracing", "--quick"], cwd=ROOT, capture_output=True, text=True, timeout=240
    )
    assert done.returncode == 0, done.stderr[-2000:]
    rows = {line.split("|")[1].strip(): line.split("|") for line in done.stdout.splitlines() if line.startswith("| ")}
    assert {"off", "1%", "100%"} <= set(rows)
    assert float(rows["off"][-2]) == 0 and float(rows["100%"][-2]) == 8  # spans per frame: robot 3, netapp 5
    assert "load average" in done.stdout
