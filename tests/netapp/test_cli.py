"""The command line: `netapp serve` fails clearly on a bad model, `netapp stream` reports a summary."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np

from netapp.cli import command_in
from netapp.serve_process import free_port, wait_http_ok


def netapp(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "netapp", *args], capture_output=True, text=True, timeout=timeout)


def modules_after_parsing(*argv: str) -> list[str]:
    """The project's modules that parsing `netapp ARGV` imports, in a fresh interpreter."""
    code = (
        "import sys; from netapp.cli import build_parser, command_in; "
        f"argv = {list(argv)!r}; build_parser(command_in(argv)).parse_args(argv); "
        "print(' '.join(m for m in sys.modules if m.startswith('netapp')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return out.stdout.split()


def test_a_command_imports_only_its_own_part():
    """`netapp serve` imports no robot client and no application; `netapp stream` no server and no model."""
    served = modules_after_parsing("--log-level", "WARNING", "serve", "--model", "m.onnx")
    assert "netapp.server.cli" in served
    assert [m for m in served if m.startswith(("netapp.client", "netapp.apps", "netapp.ros"))] == []
    assert (command_in(["--log-level", "serve", "stream"]), command_in(["-h", "serve"])) == ("stream", None)
    streamed = modules_after_parsing("stream", "http://127.0.0.1:9", "--source", "0")
    assert "netapp.apps.stream" in streamed
    assert [m for m in streamed if m.startswith(("netapp.server", "netapp.models", "netapp.ros"))] == []


def test_serve_refuses_a_missing_or_unusable_model_clearly(tmp_path):
    missing = netapp("serve", "--model", str(tmp_path / "nope.onnx"))
    assert missing.returncode == 2 and "does not exist" in missing.stderr
    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"not onnx")
    bad = netapp("serve", "--model", str(garbage))
    assert bad.returncode == 2 and "cannot load ONNX model" in bad.stderr
    unreachable = netapp("serve", "--model", "http://127.0.0.1:9/model.onnx", "--download-timeout", "3")
    assert unreachable.returncode == 2
    assert "cannot download" in unreachable.stderr and "--model PATH" in unreachable.stderr


def test_serve_and_stream_end_to_end(tmp_path, tiny_model_path):
    image = tmp_path / "frame.jpg"
    cv2.imwrite(str(image), np.full((120, 160, 3), 70, np.uint8))
    port = free_port()
    server = subprocess.Popen(
        [sys.executable, "-m", "netapp", "serve", "--model", str(tiny_model_path), "--port", str(port)],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        wait_http_ok(f"http://127.0.0.1:{port}/readyz", server, timeout_s=60)
        for transport in ("http", "ws"):
            out = netapp(
                "stream",
                f"http://127.0.0.1:{port}",
                "--transport",
                transport,
                "--source",
                str(image),
                "--fps",
                "20",
                "--duration",
                "1.5",
                "--json",
            )
            assert out.returncode == 0, out.stderr
            summary = json.loads(out.stdout)
            assert summary["results"] >= 10 and summary["errors"] == 0 and summary["lost"] == 0
            assert summary["latency_ms"]["p50"] > 0 and summary["detections"] == {"robot": summary["results"]}
        human = netapp("stream", f"http://127.0.0.1:{port}", "--source", str(image), "--fps", "10", "--duration", "1")
        assert human.returncode == 0 and "results" in human.stdout and "p50" in human.stdout
        assert "sent" in human.stderr  # the progress line
    finally:
        server.terminate()
        server.wait(timeout=15)
    assert server.returncode in (0, -15)


def test_stream_reports_an_unknown_source(tiny_server):
    out = netapp("stream", tiny_server.url, "--source", "/no/such/video.avi", "--duration", "1")
    assert out.returncode == 1 and "no such video" in out.stderr


def test_stream_through_an_unreachable_middleware_is_a_clear_error(tmp_path):
    image = tmp_path / "frame.jpg"
    cv2.imwrite(str(image), np.full((60, 80, 3), 70, np.uint8))
    out = netapp(
        "stream",
        "--middleware",
        "http://127.0.0.1:9",
        "--robot-id",
        "r1",
        "--secret",
        "s",
        "--source",
        str(image),
        "--duration",
        "1",
    )
    assert out.returncode == 1 and out.stderr.startswith("error:") and "Traceback" not in out.stderr


def test_serve_refuses_lanes_below_one_clearly(tiny_model_path):
    out = netapp("serve", "--model", str(tiny_model_path), "--lanes", "0")
    assert out.returncode == 2 and "--lanes" in out.stderr and "'0' is not a whole number of 1 or more" in out.stderr
