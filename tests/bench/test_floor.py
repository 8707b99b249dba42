"""bench/floor.py end to end, quick: real floor servers (one thread, and uvloop with a lane) and a real netapp beside
`direct`, each row with the time outside the model; one model thread everywhere (`--model-threads`, which each of
the three takes by its own option)."""

from __future__ import annotations

import json

from tests.support.bench_runs import run_bench


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
