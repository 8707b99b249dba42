"""A netapp for a benchmark: `netapp serve` as its own process on a free loopback port, stopped on exit."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

from netapp.serve_process import free_port, serve_command, wait_http_ok

# The robot transports a benchmark names -> NetAppClient's (transport, codec); "frames-h264" is H.264 over frames.
CLIENT_TRANSPORTS = {
    "http": ("http", None),
    "ws": ("ws", None),
    "h264": ("h264", None),
    "frames": ("frames", None),
    "frames-h264": ("frames", "h264"),
}
ENCODES_LIVE = ("h264", "frames-h264")  # robots given raw frames, encoding video as they send


VARIANTS_HELP = (
    "checkouts compared side by side, 'NAME=DIR,NAME2=DIR2' (e.g. base=../wt-base,new=.): each runs its own netapp and "
    "client code, interleaved. 'NAME=DIR ARGS' adds serve arguments to that variant's netapp (e.g. "
    "'pool=. --prepare-threads 2,lane=. --prepare-threads 0')"
)


def parse_variants(text: str, serve_args: Sequence[str]) -> tuple[dict[str, str], dict[str, list[str]]]:
    """`--variants` -> ({name: its checkout's folder, "" for this one}, {name: its `netapp serve` arguments});
    ValueError naming a folder that holds no netapp checkout. Empty text: this checkout alone, named ""."""
    given = dict(v.partition("=")[::2] for v in text.split(",")) if text else {"": ""}
    variants, args = {}, {}
    for name, value in given.items():
        code, _, extra = value.partition(" ")  # 'DIR --option VALUE': that checkout's netapp with more options
        if code and not (Path(code) / "netapp" / "__init__.py").is_file():
            raise ValueError(f"--variants {name}={value}: no netapp checkout there (the folder that holds netapp/)")
        variants[name] = str(Path(code).resolve()) if code else ""
        args[name] = [*serve_args, *extra.split()]
    return variants, args


@contextlib.contextmanager
def netapp_process(
    model: str, serve_args: Sequence[str] = (), code: str | None = None, cpus: str | None = None
) -> Iterator[tuple[subprocess.Popen, int]]:
    """Yield the running netapp and its port once /readyz answers; terminated (then killed) on exit. `code`: the
    folder of another checkout whose netapp package to run (a benchmark's before/after variants); `cpus`: the CPUs
    it may run on (`taskset -c` list, as a pod's CPU limit: every thread of it, the model's too)."""
    port = free_port()
    # `python -m netapp` imports from its working folder first, so a variant runs from its own checkout.
    command = serve_command("--model", os.path.abspath(model), "--port", str(port), *serve_args)
    if cpus is not None:
        command = ["taskset", "-c", cpus, *command]
    server = subprocess.Popen(command, cwd=code or None)
    try:
        wait_http_ok(f"http://127.0.0.1:{port}/readyz", server, 120)
        yield server, port
    finally:
        server.terminate()
        try:
            server.wait(timeout=20)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()


def start_run(name: str, out: str, inputs: Sequence[str]) -> Path | None:
    """A benchmark's start: its input files exist (else a one-line hint and None), SIGTERM runs the clean-up (no
    netapp left behind), and a fresh folder for this run's results."""
    for path in inputs:
        if not Path(path).is_file():
            print(f"missing {path}: pass --model / --video (the shared model and media live in ../shared)")
            return None
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    out_dir = Path(out) / time.strftime(f"{name}-%Y%m%d-%H%M%S")
    out_dir.mkdir(parents=True, exist_ok=True)
    return out_dir
