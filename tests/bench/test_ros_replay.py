"""bench/ros_replay.py: a quick replay over loopback and through the emulated 1.5 Mbit/s uplink, adapting and
sending full frames side by side (a real netapp, the link emulator, real clients)."""

from __future__ import annotations

import json

import pytest

from tests.support.bench_runs import run_bench

pytest.importorskip("rosbags")


def test_a_quick_replay_runs_each_uplink_and_mode(tmp_path, real_model_path, media_dir):
    run, stdout = run_bench(
        "ros_replay",
        tmp_path,
        real_model_path,
        media_dir / "pedestrians.avi",
        *("--uplinks", "loopback,1.5", "--modes", "auto,full", "--link-mode", "userspace"),
    )
    rows = {(r["uplink"], r["mode"]): r for r in json.loads((run / "summary.json").read_text())["rows"]}
    assert set(rows) == {("loopback", "auto"), ("loopback", "full"), ("1.5", "auto"), ("1.5", "full")}
    assert all(r["results"] > 0 for r in rows.values())
    assert rows["1.5", "auto"]["settings"] is not None and rows["1.5", "full"]["settings"] is None
    assert rows["1.5", "full"]["kb_per_frame"] > rows["1.5", "auto"]["kb_per_frame"]  # the recorded JPEG as it is
    assert rows["1.5", "auto"]["link"] == "userspace" and "| 1.5 Mbit/s (userspace) | --adapt auto |" in stdout
