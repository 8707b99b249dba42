"""`netapp serve --processor package.module:Class` serves a custom processor like the detector, and `netapp stream`
prints its output (summary, --json, --jsonl); a bad --processor is one line and exit code 2."""

from __future__ import annotations

import json
import socket
import subprocess
import sys

import cv2
import numpy as np
import pytest

from netapp.builtin_processors import BUILTIN, DEFAULT
from netapp.serve_process import free_port, wait_http_ok
from netapp.server.processor_loading import ProcessorUnavailable, processor_class
from tests.support.paths import ROOT


def netapp(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "netapp", *args], capture_output=True, text=True, timeout=timeout, cwd=ROOT
    )


def test_serve_a_custom_processor_and_stream_prints_its_output(tmp_path):
    image = tmp_path / "frame.png"
    cv2.imwrite(str(image), np.full((48, 64, 3), (10, 20, 30), np.uint8))
    port = free_port()
    server = subprocess.Popen(
        [sys.executable, "-m", "netapp", "serve", "--processor", "tests.support.sample_processor:MeanColour"]
        + ["--port", str(port)],
        cwd=ROOT,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        wait_http_ok(f"http://127.0.0.1:{port}/readyz", server, timeout_s=60)
        url = f"http://127.0.0.1:{port}"
        lines = tmp_path / "results.jsonl"
        out = netapp("stream", url, "--source", str(image), "--duration", "1", "--json", "--jsonl", str(lines))
        assert out.returncode == 0, out.stderr
        summary = json.loads(out.stdout)
        assert summary["processor"] == "mean-colour MeanColour"
        assert json.loads(summary["outputs"]) == {"mean_bgr": [10.0, 20.0, 30.0]}
        record = json.loads(lines.read_text().splitlines()[0])
        assert record["output"] == {"mean_bgr": [10.0, 20.0, 30.0]} and record["detections"] == []
        human = netapp("stream", url, "--source", str(image), "--duration", "1")
        assert 'last output     {"mean_bgr": [10.0, 20.0, 30.0]}' in human.stdout
        assert "processor       mean-colour MeanColour" in human.stdout
    finally:
        server.terminate()
        server.wait(timeout=15)


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("tracking", "unknown processor 'tracking': give one of object-detection, object-tracking, or package"),
        ("no_such_module:X", "cannot import 'no_such_module'"),
        ("tests.support.sample_processor:Nope", "module 'tests.support.sample_processor' has no 'Nope'"),
        ("tests.support.sample_processor:NotAProcessor", "is not a subclass of netapp.sdk.Processor"),
    ],
)
def test_a_bad_processor_is_one_clear_line(spec, message):
    with pytest.raises(ProcessorUnavailable, match=message.replace("(", r"\(").replace(")", r"\)")):
        processor_class(spec)


def test_the_command_line_says_what_is_missing():
    out = netapp("serve", "--port", str(free_port()))
    assert out.returncode == 2 and out.stderr.strip().endswith(
        "object-detection needs --model (an ONNX file or an http(s) URL)"
    )
    out = netapp(
        "serve",
        "--processor",
        "tests.support.sample_processor:MeanColour",
        "--model",
        "m.onnx",
        "--port",
        str(free_port()),
    )
    assert out.returncode == 2 and "--model is for the built-in processors" in out.stderr
    assert DEFAULT in BUILTIN


def test_serve_on_a_busy_port_says_so_in_one_line_and_exits_2():
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code = (
            "from netapp.sdk import Processor\nfrom netapp.server import serve\n"
            "class Echo(Processor):\n    def process(self, batch):\n        return [{} for _ in batch]\n"
            f"serve(Echo(), port={port})\n"
        )
        done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [
        f"netapp: port {port} on 127.0.0.1 is in use by another program: stop it or pick another port"
    ]
