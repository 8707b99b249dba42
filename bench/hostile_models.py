"""bench/hostile.py's model-file attacks (issue 45, rows 9 to 11): `netapp serve` started on a hostile model beside
the running netapp and its good robot. Each must end in one line and exit 2, within the memory a netapp has (the
chart's 512 MB): a start-up refusal has no /metrics of its own, its exit code and line are what it counts."""

from __future__ import annotations

import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tests.support.onnx_models import dynamic_model, hungry_model, ultralytics_metadata, yolov8_model
from tests.support.watch import PeakRss

BOX = (8.0, 16.0, 40.0, 48.0)


def names_model(path: Path, count: int, length: int) -> Path:
    names = [f"{i:0{length}d}" for i in range(count)]
    return yolov8_model(path, BOX, 1, metadata=ultralytics_metadata("detect", names))


MODELS: dict[str, Callable[[Path], Path]] = {
    "model-names-54mb": lambda p: names_model(p, 1_000_000, 44),  # 54 MB of names as Ultralytics writes them
    "model-names-1m": lambda p: names_model(p, 1_000_000, 1),
    "model-imgsz-20000": lambda p: dynamic_model(p, ultralytics_metadata("detect", ["a", "b"], (20000, 20000))),
    "model-memory-4gb": lambda p: hungry_model(p, 4_000),
    "model-memory-20gb": lambda p: hungry_model(p, 20_000),
}


def refused_at_start(name: str) -> Callable[[Any], tuple[int, int, str]]:
    """Starts `netapp serve` on the model `name` builds; lost when it does not exit 2 in one line."""

    def attack(_target: Any) -> tuple[int, int, str]:
        with tempfile.TemporaryDirectory() as tmp:
            model = MODELS[name](Path(tmp) / f"{name}.onnx")
            size = model.stat().st_size / 2**20
            command = [sys.executable, "-m", "netapp", "serve", "--model", str(model), "--port", "0"]
            process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            with PeakRss(process.pid) as rss:
                out, err = process.communicate(timeout=300)
            lines = [line for line in err.splitlines() if line.strip() and "onnxruntime" not in line]
            last = lines[-1] if lines else ""
            clean = process.returncode == 2 and "Traceback" not in err + out
            return (
                1,
                int(not clean),
                (f"{size:.0f} MB file: exit {process.returncode}, peak {rss.peak / 2**20:.0f} MiB, {last[:160]!r}"),
            )

    return attack


MODEL_ATTACKS: dict[str, Callable[[Any], tuple[int, int, str]]] = {name: refused_at_start(name) for name in MODELS}
