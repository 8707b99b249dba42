"""bench/floor.py end to end, quick: real floor servers (one thread, and uvloop with a lane) and a real netapp beside
`direct`, each row with the time outside the model; one model thread everywhere (`--model-threads`, which each of
the three takes by its own option)."""

from __future__ import annotations

import json

import pytest

from bench.netapps import parse_variants
from tests.support.bench_runs import run_bench
from tests.support.paths import ROOT


def test_the_floors_run_beside_direct_and_the_netapp(tmp_path, real_model_path, media_dir):
    video = media_dir / "pedestrians.avi"
    run, stdout = run_bench(
        "floor",
        tmp_path,
        real_model_path,
        video,
        *("--floors", "inline,asyncio", "--transports", "frames", "--model-threads", "1"),
    )
    rows = {r["transport"]: r for r in json.loads((run / "runs.json").read_text())}
    assert set(rows) == {"direct", "floor-inline", "floor-asyncio", "frames"}
    assert all(r["results"] > 0 and r["outside_model_ms"] is not None for r in rows.values())
    assert "floor-asyncio @ 25 FPS: overhead outside the model" in stdout


def test_two_checkouts_side_by_side_with_their_start_times(tmp_path, real_model_path, media_dir):
    run, stdout = run_bench(
        "floor",
        tmp_path,
        real_model_path,
        media_dir / "pedestrians.avi",
        *("--floors", "inline", "--transports", "frames", "--model-threads", "1"),
        *("--variants", f"before={ROOT},after={ROOT}", "--starts", "1"),
    )
    rows = json.loads((run / "runs.json").read_text())
    assert sorted(r["variant"] for r in rows if r["transport"] == "frames") == ["after", "before"]
    assert [r["variant"] for r in rows if r["transport"] != "frames"] == ["", ""]  # direct and the floor: once
    start_table = stdout[stdout.index("| netapp | starts | exec -> /readyz") :].split("\n\n")[0]
    starts = [line.split("|")[1:4] for line in start_table.splitlines()[2:]]
    assert [(name.strip(), count.strip()) for name, count, _ in starts] == [("before", "1"), ("after", "1")]
    assert all(0 < float(p50) < 120 for _, _, p50 in starts)


def test_a_variant_without_a_checkout_is_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match=r"--variants old=.*no netapp checkout there"):
        parse_variants(f"old={tmp_path}", [])
    variants, serve_args = parse_variants(f"new={ROOT} --prepare-threads 0", ["--lanes", "1"])
    assert variants == {"new": str(ROOT)} and serve_args == {"new": ["--lanes", "1", "--prepare-threads", "0"]}
