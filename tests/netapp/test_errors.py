"""Every error a user can cause is one line that says what to do, with the documented exit code."""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import pytest

from netapp.client.urls import BadURL, http_url
from netapp.models.source import ModelUnavailable, resolve_model


def netapp(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "netapp", *args], capture_output=True, text=True, timeout=timeout)


def one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1, text
    return lines[0]


def test_version():
    from netapp import __version__

    out = netapp("--version")
    assert out.returncode == 0 and out.stdout.strip() == f"netapp {__version__}"


def test_a_url_without_a_scheme_says_what_to_type(tmp_path):
    out = netapp("stream", "127.0.0.1:5896", "--source", str(tmp_path / "x.jpg"), "--duration", "1")
    assert out.returncode == 1
    assert "must start with http:// or https://" in one_line(out.stderr) and "http://127.0.0.1:5896" in out.stderr
    with pytest.raises(BadURL):
        http_url("edge:5896")
    assert http_url("https://edge.example.com/") == "https://edge.example.com"


def test_a_port_in_use_suggests_another(tiny_model_path):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        out = netapp("serve", "--model", str(tiny_model_path), "--port", str(port))
    assert out.returncode == 2
    assert one_line(out.stderr).endswith(
        f"port {port} on 127.0.0.1 is in use by another program: stop it or pick another --port"
    )


def test_a_model_url_with_no_network_is_short(tmp_path):
    with socket.socket() as closed:
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]  # nothing listens here: the connection is refused, as with no network
    with pytest.raises(ModelUnavailable) as caught:
        resolve_model(f"http://127.0.0.1:{port}/m.onnx", cache_dir=tmp_path, timeout_s=2)
    message = str(caught.value)
    assert "cannot connect (no network, or a wrong address)" in message and "--model PATH" in message
    assert len(message) < 300 and "urllib3" not in message
    with pytest.raises(ModelUnavailable, match="cannot download the sample image from"):
        resolve_model(
            f"http://127.0.0.1:{port}/dog.jpg", cache_dir=tmp_path, option="--source", what="the sample image"
        )


def startup(tmp_path, *args: str, kubeconfig: str | None = None) -> subprocess.CompletedProcess:
    """`netapp ARGS` with no cluster configured: HOME has no ~/.kube, no KUBECONFIG, not in a pod."""
    env = {k: v for k, v in os.environ.items() if k not in ("KUBECONFIG", "KUBERNETES_SERVICE_HOST")}
    env["HOME"] = str(tmp_path)
    if kubeconfig:
        env["KUBECONFIG"] = kubeconfig
    return subprocess.run([sys.executable, "-m", "netapp", *args], capture_output=True, text=True, timeout=60, env=env)


def test_middleware_robots_file_missing_or_holding_a_plain_secret(tmp_path):
    out = startup(tmp_path, "middleware", "--robots-file", str(tmp_path / "robots.yaml"))
    assert out.returncode == 2
    assert one_line(out.stderr) == (
        f"netapp middleware: --robots-file {tmp_path / 'robots.yaml'} does not exist: create it (see "
        "docs/middleware.md) or fix the path"
    )
    plain = tmp_path / "plain.yaml"
    plain.write_text("robots:\n  robot-1: s3cret\n")
    out = startup(tmp_path, "middleware", "--robots-file", str(plain))
    assert out.returncode == 2 and "use `netapp middleware hash-secret`" in one_line(out.stderr)


def test_no_cluster_is_one_line_for_the_middleware_and_the_operator(tmp_path):
    out = startup(tmp_path, "middleware", "--backend", "kubernetes")
    assert out.returncode == 2
    assert one_line(out.stderr).startswith("netapp middleware: no Kubernetes cluster configured")
    assert out.stderr.strip().endswith("(or use --backend local)")
    out = startup(tmp_path, "operator")
    assert out.returncode == 2
    assert one_line(out.stderr) == (
        f"netapp operator: no Kubernetes cluster configured (no {tmp_path / '.kube' / 'config'}): "
        "set KUBECONFIG or run in a cluster"
    )


def test_an_unreachable_cluster_stops_the_operator_at_once(tmp_path):
    with socket.socket() as closed:
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
    kubeconfig = tmp_path / "kubeconfig"
    kubeconfig.write_text(
        f"apiVersion: v1\nclusters: [{{name: c, cluster: {{server: 'https://127.0.0.1:{port}'}}}}]\n"
        "contexts: [{name: lab, context: {cluster: c, user: u}}]\ncurrent-context: lab\nusers: [{name: u, user: {}}]\n"
    )
    out = startup(tmp_path, "operator", kubeconfig=str(kubeconfig))
    assert out.returncode == 2
    assert one_line(out.stderr) == (
        f"netapp operator: cannot reach the Kubernetes API at https://127.0.0.1:{port} (context 'lab' of "
        f"{kubeconfig}): Connection refused; is the cluster running?"
    )


def test_a_middleware_port_in_use_suggests_another(tmp_path):
    robots = tmp_path / "robots.yaml"
    robots.write_text("robots: {}\n")
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        out = startup(tmp_path, "middleware", "--robots-file", str(robots), "--host", "127.0.0.1", "--port", str(port))
    assert out.returncode == 2 and one_line(out.stderr).endswith("pick another --port")
