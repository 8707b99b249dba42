"""Cold start benchmark: what a robot waits for when its netapp is not running yet, part by part.

    python -m bench.coldstart [--starts 5] [--variants base=/work/wt/base,new=.] [--model M] [--image I] [--source]

Each start, interleaved across the variants (checkouts, as bench.floor's --variants), measures:

- the interpreter: `python -c pass` (exec -> exit);
- the imports `netapp serve` does before it serves (`netapp.server.cli` and `netapp.server.runner`, in a process of
  their own, as the variant's start-up does them: with the collector paused where it has `netapp.startup`);
- the model's load and first run (the processor `netapp serve` builds, loaded, in that process after its imports);
- exec -> /readyz answering 200 of a real `netapp serve` (polled every 5 ms); "serving up" is what is left of it
  once the three above are taken off (the app, the event loop, the listening socket);
- the robot: connecting to the ready netapp (`NetAppClient`, the frames transport) and its first result.

Before the starts, each variant's own modules (`netapp/`, `operator/`) are compiled to bytecode, as an installed
netapp has them (pip and the netapp image compile at install: docs/images.md#start-to-ready); `--source` leaves a
checkout as it is, which under PYTHONDONTWRITEBYTECODE (a development shell's) compiles some 170 modules at every
start.

The decision that starts a netapp (the middleware's, on a robot's move) is bench.switchover's: its line "the
cloud netapp started" is the time from the crossing to the netapp's exec. A pod's start on Kubernetes (scheduling,
the image and the model, the kubelet's probes) is docs/kubernetes.md#start-up-time.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
import urllib.request
from collections.abc import Sequence
from pathlib import Path

from netapp.serve_process import free_port, serve_command

ROOT = Path(__file__).resolve().parent.parent
PARTS = ("interpreter", "imports", "model load + first run", "serving up", "exec -> ready", "connect", "first result")

# Run in the variant's checkout: the imports and the model's load, timed in-process (one JSON line out).
PHASES = """
import json, sys, time, contextlib
began = time.perf_counter()
try:
    from netapp.startup import collector_paused
except ImportError:  # a checkout before it: its start-up runs with the collector on
    collector_paused = contextlib.nullcontext
with collector_paused():
    import argparse
    import netapp.server.cli as cli
    import netapp.server.runner
    imported = time.perf_counter()
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    from netapp.server.processor_loading import build_processor
    build_processor(parser.parse_args(["--model", sys.argv[1]]))
    loaded = time.perf_counter()
print(json.dumps({"imports": imported - began, "model load + first run": loaded - imported}))
"""


def interpreter_s(code: str) -> float:
    began = time.monotonic()
    subprocess.run([sys.executable, "-c", "pass"], cwd=code, check=True)
    return time.monotonic() - began


def phases(code: str, model: str) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.path.abspath(code), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run(
        [sys.executable, "-c", PHASES, model], cwd=code, env=env, check=True, capture_output=True, text=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def serve_and_robot(code: str, model: str, frame: bytes) -> dict[str, float]:
    """exec -> /readyz of `netapp serve` from `code`, then a robot's connection and first result."""
    from netapp.client.netapp_client import NetAppClient

    port = free_port()
    began = time.monotonic()
    server = subprocess.Popen(serve_command("--model", os.path.abspath(model), "--port", str(port)), cwd=code)
    try:
        url = f"http://127.0.0.1:{port}"
        while True:
            if server.poll() is not None:
                raise RuntimeError(f"netapp serve exited with {server.returncode} before /readyz answered")
            try:
                with urllib.request.urlopen(f"{url}/readyz", timeout=1) as answer:
                    if answer.status == 200:
                        break
            except OSError:
                pass
            time.sleep(0.005)  # polling a starting process: nothing to wait on
        ready = time.monotonic()
        with NetAppClient(url, transport="frames", max_in_flight=1) as client:
            connected = time.monotonic()
            client.send(frame)
            if next(client.results(timeout=30), None) is None:
                raise RuntimeError("no result for the robot's first frame in 30 s")
            first = time.monotonic()
    finally:
        server.terminate()
        server.wait(20)
    return {"exec -> ready": ready - began, "connect": connected - ready, "first result": first - connected}


def compile_bytecode(code: str) -> None:
    """The variant's own packages compiled (their __pycache__ beside them, as an install leaves them)."""
    folders = [str(Path(code) / p) for p in ("netapp", "operator") if (Path(code) / p).is_dir()]
    subprocess.run([sys.executable, "-m", "compileall", "-q", *folders], check=True, stdout=subprocess.DEVNULL)


def one_start(code: str, model: str, frame: bytes) -> dict[str, float]:
    row = {"interpreter": interpreter_s(code), **phases(code, model), **serve_and_robot(code, model, frame)}
    row["serving up"] = row["exec -> ready"] - row["interpreter"] - row["imports"] - row["model load + first run"]
    return row


def table(rows: dict[str, list[dict[str, float]]]) -> str:
    """Median (min-max) of each part, a column per variant, in ms."""
    lines = ["| part (ms, median (min-max)) | " + " | ".join(rows) + " |", "|---|" + "---|" * len(rows)]
    for part in PARTS:
        cells = []
        for runs in rows.values():
            values = [1000 * r[part] for r in runs]
            cells.append(f"{statistics.median(values):.0f} ({min(values):.0f}-{max(values):.0f})")
        lines.append(f"| {part} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def parse_variants(text: str) -> dict[str, str]:
    variants = {}
    for item in filter(None, (v.strip() for v in text.split(","))):
        name, _, path = item.partition("=")
        variants[name] = path or "."
    return variants


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default=str(ROOT.parent / "shared/models/yolox_nano.onnx"))
    parser.add_argument("--image", default=str(ROOT.parent / "shared/media/dog.jpg"), help="the robot's JPEG frame")
    parser.add_argument("--starts", type=int, default=5, help="cold starts per variant, interleaved (default 5)")
    parser.add_argument("--variants", default="this=.", help="name=checkout,... (default: this checkout)")
    parser.add_argument("--source", action="store_true", help="do not compile the variants' modules first")
    args = parser.parse_args(argv)
    for path, what in ((args.model, "--model"), (args.image, "--image")):
        if not Path(path).is_file():
            print(f"{what} {path} does not exist: give one (the shared model and media live in ../shared)")
            return 2
    variants = parse_variants(args.variants)
    frame = Path(args.image).read_bytes()
    if not args.source:
        for code in variants.values():
            compile_bytecode(code)
    rows: dict[str, list[dict[str, float]]] = {name: [] for name in variants}
    for start in range(args.starts):
        for name, code in variants.items():
            row = one_start(code, args.model, frame)
            rows[name].append(row)
            print(f"{name} start {start + 1}: " + ", ".join(f"{k} {1000 * row[k]:.0f} ms" for k in PARTS), flush=True)
    how = "from source (no bytecode)" if args.source else "bytecode compiled first, as installed"
    print(f"\n{args.starts} cold starts per variant, interleaved, {how}; load average {os.getloadavg()[0]:.2f}\n")
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
