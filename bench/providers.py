"""The model's own time by onnxruntime execution provider: CPU, CUDA, TensorRT (FP32 and FP16), at batch 1 and more.

    python -m bench.providers                                         # YOLOX-Nano, every provider present
    python -m bench.providers --models a.onnx,b.onnx --devices cuda,tensorrt-fp16 --batches 1,8 --runs 300
    python -m bench.providers --make-dynamic M.onnx --out M-dynamic.onnx   # a batch-dynamic copy (when it runs)

Each row is one InferenceSession on one model: `session.run` with a NumPy input of the model's size, as the netapp
calls it (so host-device copies are in), after `--warmup` untimed runs; TensorRT's first run builds its engine
(timed apart as `first run s`, and kept in `--trt-cache` for the next start). A model whose batch is fixed at 1 gets
batch rows through a batch-dynamic copy, made only when the copy gives the same output as the original
(YOLOX-Nano's does; YOLO11's reshapes are fixed to batch 1). Prints a markdown table; `--json FILE` keeps the rows.
The GPU libraries come from NVIDIA's wheels (`netapp.models.providers.preload`).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from netapp.models.providers import preload, provider_options
from tests.support.paths import SHARED

CPU, CUDA, TENSORRT = "CPUExecutionProvider", "CUDAExecutionProvider", "TensorrtExecutionProvider"
DEVICES = ("cpu", "cuda", "tensorrt", "tensorrt-fp16")
MAX_BATCH = 64  # the largest batch a TensorRT profile is built for here


@dataclass(frozen=True)
class Row:
    model: str
    device: str
    batch: int
    p50_ms: float | None = None
    p95_ms: float | None = None
    images_per_s: float | None = None
    first_run_s: float | None = None
    note: str = ""


def providers(device: str, input_name: str, shape: Sequence[int], cache: Path) -> list:
    """onnxruntime's provider list for `device` (a TensorRT engine cached in `cache`, CUDA then CPU as fallback)."""
    if device == "cpu":
        return [CPU]
    if device == "cuda":
        return [CUDA, CPU]
    dims = "x".join(str(d) for d in shape)
    options = {
        **provider_options("tensorrt", str(cache), device == "tensorrt-fp16"),  # the netapp's own options
        # one shape: the engine is built for the batch it is timed at
        "trt_profile_min_shapes": f"{input_name}:{dims}",
        "trt_profile_opt_shapes": f"{input_name}:{dims}",
        "trt_profile_max_shapes": f"{input_name}:{dims}",
    }
    return [(TENSORRT, options), CUDA, CPU]


def _provider_for(device: str) -> str:
    return {"cpu": CPU, "cuda": CUDA}.get(device, TENSORRT)


def make_dynamic(source: Path, target: Path) -> bool:
    """A copy of `source` whose batch dimension is free, kept only when batch 2 gives what batch 1 gives (a graph
    that reshapes to a fixed batch fails or differs); returns whether `target` was written."""
    import onnx
    import onnxruntime as ort

    model = onnx.load(str(source))
    for value in [*model.graph.input, *model.graph.output]:
        value.type.tensor_type.shape.dim[0].dim_param = "batch"
    del model.graph.value_info[:]  # inferred shapes with the fixed batch would contradict the free one
    onnx.save(model, str(target))
    try:
        original = ort.InferenceSession(str(source), providers=[CPU])
        copy = ort.InferenceSession(str(target), providers=[CPU])
        name, shape = original.get_inputs()[0].name, original.get_inputs()[0].shape
        x = np.random.default_rng(0).random((2, *shape[1:]), dtype=np.float32)
        one = original.run(None, {name: x[1:2]})[0]
        two = copy.run(None, {name: x})[0]
        same = two.shape[0] == 2 and np.allclose(two[1:2], one, atol=1e-4)
    except Exception:  # noqa: BLE001 - any failure means the graph is tied to its batch
        same = False
    if not same:
        target.unlink(missing_ok=True)
    return same


def _fixed_shape(session) -> tuple[str, list[int]]:
    inp = session.get_inputs()[0]
    return inp.name, [d if isinstance(d, int) else 1 for d in inp.shape]


def time_one(model: Path, device: str, batch: int, runs: int, warmup: int, cache: Path) -> Row:
    """One row: the model on `device` at `batch`, or a row saying why it could not run."""
    import onnxruntime as ort

    label = model.stem
    if _provider_for(device) not in ort.get_available_providers():
        return Row(label, device, batch, note=f"{_provider_for(device)} not in this onnxruntime")
    probe = ort.InferenceSession(str(model), providers=[CPU])
    name, shape = _fixed_shape(probe)
    fixed = probe.get_inputs()[0].shape[0] == 1
    del probe
    path = model
    if batch > 1 and fixed:
        path = cache / f"{model.stem}-dynamic.onnx"
        if not path.exists() and not make_dynamic(model, path):
            return Row(label, device, batch, note="batch fixed at 1 in the graph")
    shape = [batch, *shape[1:]]
    try:
        session = ort.InferenceSession(str(path), providers=providers(device, name, shape, cache))
    except Exception as exc:  # noqa: BLE001 - a provider that cannot start (no GPU, missing libraries) is a row
        return Row(label, device, batch, note=f"could not start: {str(exc).splitlines()[0][:120]}")
    if session.get_providers()[0] != _provider_for(device):
        return Row(label, device, batch, note=f"fell back to {session.get_providers()[0]} (see the log above)")
    x = np.random.default_rng(0).random(shape, dtype=np.float32)
    started = time.perf_counter()
    session.run(None, {name: x})  # TensorRT builds (or loads) its engine here
    first = time.perf_counter() - started
    for _ in range(warmup):
        session.run(None, {name: x})
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        session.run(None, {name: x})
        times.append((time.perf_counter() - t0) * 1000)
    p50 = statistics.median(times)
    p95 = statistics.quantiles(times, n=100, method="inclusive")[94] if len(times) > 1 else p50
    return Row(label, device, batch, round(p50, 4), round(p95, 4), round(batch * 1000 / p50, 1), round(first, 2))


def table(rows: Sequence[Row]) -> str:
    lines = [
        "| model | device | batch | p50 ms | p95 ms | images/s | first run s | note |",
        "|---|---|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        cells = [r.p50_ms, r.p95_ms, r.images_per_s, r.first_run_s]
        shown = ["" if v is None else f"{v:g}" for v in cells]
        lines.append(f"| {r.model} | {r.device} | {r.batch} | {' | '.join(shown)} | {r.note} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.providers", description=__doc__.split("\n\n")[0])
    p.add_argument("--models", default=str(SHARED / "models" / "yolox_nano.onnx"), help="ONNX files, comma-separated")
    p.add_argument("--devices", default=",".join(DEVICES), help=f"some of {', '.join(DEVICES)}")
    p.add_argument("--batches", default="1,8", help="batch sizes, comma-separated")
    p.add_argument("--runs", type=int, default=200)
    p.add_argument("--warmup", type=int, default=20)
    p.add_argument("--trt-cache", help="where TensorRT keeps its engines (default: a temporary folder)")
    p.add_argument("--json", help="write the rows here too")
    p.add_argument("--make-dynamic", metavar="MODEL", help="write a batch-dynamic copy of MODEL to --out, and stop")
    p.add_argument("--out", help="with --make-dynamic: the copy's path")
    args = p.parse_args(argv)
    if args.make_dynamic:
        if not args.out:
            p.error("--make-dynamic needs --out")
        if not make_dynamic(Path(args.make_dynamic), Path(args.out)):
            print(f"{args.make_dynamic}: its graph is tied to batch 1; no copy written", file=sys.stderr)
            return 1
        print(args.out)
        return 0
    devices = args.devices.split(",")
    if unknown := [d for d in devices if d not in DEVICES]:
        p.error(f"unknown --devices {', '.join(unknown)}: give some of {', '.join(DEVICES)}")
    batches = [int(b) for b in args.batches.split(",")]
    if any(not 1 <= b <= MAX_BATCH for b in batches):
        p.error(f"--batches are 1 to {MAX_BATCH}")
    models = [Path(m) for m in args.models.split(",") if m]
    if missing := [str(m) for m in models if not m.is_file()]:
        print(f"missing {', '.join(missing)}: pass --models (the shared ones are in ../shared/models)", file=sys.stderr)
        return 2
    print(preload().describe(), file=sys.stderr)
    import onnxruntime as ort

    print(f"onnxruntime {ort.__version__}: {', '.join(ort.get_available_providers())}", file=sys.stderr)
    with tempfile.TemporaryDirectory(prefix="trt-cache-") as scratch:
        cache = Path(args.trt_cache or scratch)
        cache.mkdir(parents=True, exist_ok=True)
        rows = []
        for model in models:
            for device in devices:
                for batch in batches:
                    rows.append(time_one(model, device, batch, args.runs, args.warmup, cache))
                    print(f"  {rows[-1]}", file=sys.stderr, flush=True)
    print(table(rows))
    if args.json:
        Path(args.json).write_text(json.dumps([asdict(r) for r in rows], indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
