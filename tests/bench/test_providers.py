"""bench/providers.py and bench/gpu.sh, the prepared GPU run: the rows it makes on the CPU, a batch-dynamic copy
only where the graph allows one, and the script's refusals (the whole run is `bench/gpu.sh` with DEVICE=cpu, minutes:
docs/benchmarks.md#the-gpu-run)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from bench.providers import main, make_dynamic
from tests.support.paths import ROOT, SHARED


def test_a_row_per_model_device_and_batch_with_a_reason_where_none_runs(tiny_model_path, tmp_path, capsys):
    out = tmp_path / "rows.json"
    argv = ["--models", str(tiny_model_path), "--devices", "cpu,cuda", "--batches", "1,4", "--runs", "5"]
    assert main([*argv, "--warmup", "1", "--json", str(out), "--trt-cache", str(tmp_path / "cache")]) == 0
    rows = {(r["device"], r["batch"]): r for r in json.loads(out.read_text())}
    assert set(rows) == {("cpu", 1), ("cpu", 4), ("cuda", 1), ("cuda", 4)}
    row = rows[("cpu", 1)]
    assert row["p50_ms"] > 0 and row["p95_ms"] >= row["p50_ms"] and row["note"] == ""
    assert row["images_per_s"] == pytest.approx(1000 / row["p50_ms"], rel=0.05)
    # the tiny model's output is a constant of batch 1: no batch-dynamic copy of it gives the same output
    assert rows[("cpu", 4)]["p50_ms"] is None and rows[("cpu", 4)]["note"] == "batch fixed at 1 in the graph"
    assert rows[("cuda", 1)]["p50_ms"] is None and rows[("cuda", 1)]["note"]  # no GPU here: says why
    assert "| tiny_yolox | cpu | 4 |" in capsys.readouterr().out


def test_a_batch_dynamic_copy_gives_the_originals_output(real_model_path, tmp_path):
    import onnxruntime as ort

    copy = tmp_path / "dynamic.onnx"
    assert make_dynamic(real_model_path, copy)  # YOLOX-Nano's graph is free of its batch
    original, dynamic = (
        ort.InferenceSession(str(p), providers=["CPUExecutionProvider"]) for p in (real_model_path, copy)
    )
    name = original.get_inputs()[0].name
    x = np.random.default_rng(1).random((3, 3, 416, 416), dtype=np.float32)
    batched = dynamic.run(None, {name: x})[0]
    for i in range(3):
        np.testing.assert_allclose(batched[i : i + 1], original.run(None, {name: x[i : i + 1]})[0], atol=1e-4)


def test_no_copy_of_a_graph_tied_to_batch_1(tmp_path):
    export = SHARED / "models" / "exports" / "yolo11n.onnx"
    if not export.is_file():
        pytest.skip(f"{export} is absent (../shared/models/exports)")
    assert not make_dynamic(export, tmp_path / "copy.onnx")  # its attention reshapes to batch 1
    assert not (tmp_path / "copy.onnx").exists()


def test_gpu_sh_says_what_is_missing(tmp_path):
    env = {**os.environ, "PYTHON": sys.executable, "MODEL": str(tmp_path / "none.onnx"), "OUT": str(tmp_path)}
    done = subprocess.run(["bash", str(ROOT / "bench" / "gpu.sh")], env=env, capture_output=True, text=True, timeout=30)
    assert done.returncode == 2 and "none.onnx is missing: set MODEL=" in done.stderr


def test_robots_without_a_balancer_take_one_replica():
    argv = [sys.executable, "-m", "bench.robots", "--no-balancer", "--replicas", "1,2"]
    done = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "--no-balancer runs one replica" in done.stderr
