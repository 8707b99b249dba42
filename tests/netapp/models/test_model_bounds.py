"""A model file's claims are bounded before they cost anything (issue 45, rows 9 to 11): metadata values are
bounded before they are parsed, an input size over `--max-pixels` is refused, and a graph that needs more memory
than `--max-model-memory` (or fails on its first run) is refused in one line, exit 2, never a traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest

from netapp.models import Detector, DetectorConfig
from netapp.models.card import ModelRefused
from netapp.models.metadata import MAX_METADATA_CHARS, MAX_NAMES, read_metadata
from tests.support.onnx_models import dynamic_model, hungry_model, ultralytics_metadata, yolov8_model

BOX = (8.0, 16.0, 40.0, 48.0)


def serve(model, *flags: str) -> subprocess.CompletedProcess:
    """`netapp serve` on the model, as a user runs it: its exit code and output."""
    command = [sys.executable, "-m", "netapp", "serve", "--model", str(model), "--port", "0", *flags]
    return subprocess.run(command, capture_output=True, text=True, timeout=120)


def one_line_refusal(done: subprocess.CompletedProcess, *words: str) -> str:
    assert done.returncode == 2, done.stderr[-2000:]
    assert "Traceback" not in done.stderr + done.stdout
    line = next(line for line in done.stderr.splitlines() if all(w in line for w in words))
    return line


def test_big_metadata_is_refused_before_it_is_parsed():
    huge = str({i: f"class{i}" for i in range(60_000)})  # 1.2 MB: 120 MB to parse
    assert len(huge) > MAX_METADATA_CHARS
    with pytest.raises(ModelRefused, match="metadata 'names' is .* characters, over"):
        read_metadata({"task": "detect", "names": huge})
    with pytest.raises(ModelRefused, match="over 524288"):
        read_metadata({"imgsz": "[" * (MAX_METADATA_CHARS + 1)})
    many = "[" + ",".join(['""'] * (MAX_NAMES + 1)) + "]"  # within the characters, over the names
    with pytest.raises(ModelRefused, match=f"names {MAX_NAMES + 1} classes"):
        read_metadata({"names": many})
    deep = "[" * 100_000 + "]" * 100_000  # nesting past any parser's: read as nothing, never a crash
    assert read_metadata({"names": deep[:MAX_METADATA_CHARS]}).names is None
    assert read_metadata({"names": huge[:1000] + "}", "description": "x" * 10 * MAX_METADATA_CHARS}).task is None


def test_a_model_with_big_names_is_refused_by_serve_in_one_line(tmp_path):
    names = [f"class{i}" for i in range(80_000)]
    path = yolov8_model(tmp_path / "names.onnx", BOX, 1, metadata=ultralytics_metadata("detect", names))
    one_line_refusal(serve(path), "metadata 'names'")


def test_an_input_size_over_max_pixels_is_refused(tmp_path):
    path = dynamic_model(tmp_path / "dynamic.onnx", ultralytics_metadata("detect", ["a", "b"], (20000, 20000)))
    with pytest.raises(ModelRefused, match="input of 20000x20000 is over --max-pixels"):
        Detector(DetectorConfig(str(path))).load()
    line = one_line_refusal(serve(path, "--max-pixels", "1000000"), "over --max-pixels 1000000")
    assert "20000x20000" in line
    fine = dynamic_model(tmp_path / "fine.onnx", ultralytics_metadata("detect", ["a", "b"], (64, 96)))
    detector = Detector(DetectorConfig(str(fine)))
    detector.load()
    assert detector.input_hw == (64, 96)


def test_a_model_over_its_memory_budget_is_refused_in_one_line(tmp_path):
    line = one_line_refusal(serve(hungry_model(tmp_path / "hungry.onnx", 300), "--max-model-memory", "128"), "128 MB")
    assert "needs more than --max-model-memory 128 MB on its first run" in line


def test_a_graph_over_the_default_budget_or_failing_its_first_run_is_refused_in_one_line(tmp_path):
    # 3 GB against the default budget: refused at once, nothing allocated
    one_line_refusal(serve(hungry_model(tmp_path / "big.onnx", 3_000)), "--max-model-memory 1024 MB")
    # 20 GB: onnxruntime itself refuses the tensor; the graph cannot run, said in one line
    one_line_refusal(serve(hungry_model(tmp_path / "huge.onnx", 20_000)), "failed on its first run")


def test_model_inspect_refuses_an_input_over_the_default_bound_before_probing_it(tmp_path):
    from netapp.models.reading import read_model

    path = dynamic_model(tmp_path / "dynamic.onnx", ultralytics_metadata("detect", ["a", "b"], (20000, 20000)))
    with pytest.raises(ModelRefused, match="20000x20000 is over --max-pixels"):
        read_model(str(path))


def test_cuda_arena_is_capped_by_the_same_budget():
    from netapp.models.memory import gpu_limited

    providers = [
        ("TensorrtExecutionProvider", {"a": "1"}),
        ("CUDAExecutionProvider", {"device_id": "0"}),
        "CPUExecutionProvider",
    ]
    limited = gpu_limited(providers, 256)
    assert limited[0] == providers[0] and limited[2] == "CPUExecutionProvider"
    assert limited[1] == ("CUDAExecutionProvider", {"device_id": "0", "gpu_mem_limit": str(256 << 20)})
    assert gpu_limited(["CUDAExecutionProvider"], 64) == [("CUDAExecutionProvider", {"gpu_mem_limit": str(64 << 20)})]
    assert gpu_limited(providers, 0) is providers
