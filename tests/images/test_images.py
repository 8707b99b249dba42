"""The images as `make images` builds them, run as a cluster would: read-only root, their own user, their entrypoint.

The netapp image serves a detection of dog.jpg with the shared YOLOX-Nano mounted; the tracking image gives a
track id; the control-plane image's operator reconciles a NetApp against the Kubernetes emulator and its middleware
serves; the sizes stay within the goals of issue 26. Builds go through tools/images.py (buildah here, its layer
cache making a warm run quick; the Debian bases are cached per machine). Where no builder or mmdebstrap is, the
tests skip with the install hint.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import shutil
import signal
import subprocess
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from netapp.serve_process import free_port
from tests.support.kube_emulator import kubeconfig
from tests.support.paths import ROOT
from tools import images

MB = 1_000_000
# Issue 26 (were 986 and 592 MB); Pillow for classifiers: +20 MB; the broker extra for spec.publish (aio-pika,
# aiomqtt, confluent-kafka with librdkafka): +20 MB, 425 -> 440 (issue 41: 427 MB, and room for the patch releases
# pip resolves).
GOALS_MB = {"netapp": 440, "control-plane": 250}
# A code-only change rebuilds the top layer alone, and it stays this small (5 MB until this wave's 18,000 lines: 5.24)
CODE_LAYER_MB = 6
WEBRTC_GOAL_MB = (
    600  # the netapp's goal and the `webrtc` extra (aiortc and PyAV: about 134 MB, docker/netapp.Dockerfile)
)
READY_S = 2.0  # container start to /readyz with the model present

pytestmark = pytest.mark.timeout(900)  # a cold build (bases and wheels) takes about 2-3 minutes on 2 cores


def _skip_reason() -> str | None:
    builder = images.find_builder()
    if builder is None:
        return f"no image builder: {images.INSTALL_HINT}"
    if builder == "buildah" and os.geteuid() != 0:
        return "buildah builds and chroot runs need root here"
    if not (os.environ.get("PYTHON_IMAGE") or shutil.which("mmdebstrap")):
        return f"no base image: set PYTHON_IMAGE and BUILD_IMAGE, or {images.INSTALL_HINT}"
    return None


@pytest.fixture(scope="module")
def built() -> tuple[str, dict[str, str]]:
    reason = _skip_reason()
    if reason:
        pytest.skip(reason)
    builder = images.find_builder()
    return builder, images.build(list(images.DEFAULT), builder)


@pytest.fixture
def start(built) -> Iterator:
    """start(name, args, mounts, env) runs an image in the background; its process group is stopped at the end."""
    builder, refs = built
    with contextlib.ExitStack() as stack:
        procs: list[subprocess.Popen] = []

        def start_image(name: str, args: list[str], mounts: dict[str, str], env=None) -> subprocess.Popen:
            argv = stack.enter_context(images.container(builder, refs[name], args, mounts, env))
            out = subprocess.PIPE
            proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, text=True, start_new_session=True)
            procs.append(proc)
            return proc

        yield start_image
        for proc in procs:
            stop(proc)


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def wait_ready(proc: subprocess.Popen, url: str, timeout: float = 60.0) -> float:
    """Seconds until `url` answers 200 (polled); fails with the process's output if it exits first."""
    started = time.monotonic()
    while True:
        if proc.poll() is not None:
            raise AssertionError(f"the container exited ({proc.returncode}): {proc.stdout.read()[-3000:]}")
        try:
            with urllib.request.urlopen(url, timeout=1) as response:
                if response.status == 200:
                    return time.monotonic() - started
        except OSError:
            pass
        if time.monotonic() - started > timeout:
            raise AssertionError(f"{url} not ready after {timeout:.0f} s")
        time.sleep(0.02)


def serve(start, name: str, model: Path, *extra: str, env: dict[str, str] | None = None) -> tuple[str, float]:
    port = free_port()
    args = ["--host", "127.0.0.1", "--port", str(port), "--model", f"/opt/model/{model.name}", *extra]
    proc = start(name, args, {str(model.parent): "/opt/model"}, env)
    url = f"http://127.0.0.1:{port}"
    return url, wait_ready(proc, f"{url}/readyz")


def test_requirement_lists_follow_pyproject():
    """What the image builds install comes from pyproject.toml: self-references followed, or left to --no-deps."""
    import importlib.util

    import tomllib

    spec = importlib.util.spec_from_file_location("image_requirements", ROOT / "docker" / "requirements.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    server = module.requirements(project, ["server"], core=True)
    assert server[: len(project["dependencies"])] == project["dependencies"] and len(server) == len(set(server))
    tracking = module.requirements(project, ["tracking"])
    assert set(extras["tracking-runtime"]) < set(tracking) and not any("netapp-toolkit" in r for r in tracking)
    direct = module.requirements(project, ["tracking"], direct=True)
    assert direct == [r for r in extras["tracking"] if not r.startswith(project["name"])]
    with pytest.raises(SystemExit, match="no extra 'nope'"):
        module.requirements(project, ["nope"])
    # the GPU image: the server's less onnxruntime, whose CUDA build (the same module) the gpu extra brings
    gpu = module.requirements(project, ["server", "gpu"], core=True, without=frozenset({"onnxruntime"}))
    names = [r.split(">")[0].split("[")[0].split("=")[0] for r in gpu]
    assert "onnxruntime" not in names and "onnxruntime-gpu" in names and "fastapi" in names


def test_sizes_and_layers(built):
    builder, refs = built
    if builder != "buildah":
        pytest.skip("layer sizes are read from buildah's storage")
    for name, goal in GOALS_MB.items():
        layers = images.layer_sizes(builder, refs[name])
        assert sum(size for size, _ in layers) <= goal * MB, (name, layers)
        size, created_by = layers[-1]  # the project's code, alone on top
        assert "/opt/app" in created_by and size <= CODE_LAYER_MB * MB, (name, layers[-1])


def test_netapp_image_serves_a_detection_read_only_and_traced(start, real_model_path, media_dir):
    """Tracing turned on as the chart does (the OTel variables) traces in the image: its `tracing` extra is in."""
    from netapp.client import NetAppClient
    from tests.support.otlp import OtlpReceiver

    with OtlpReceiver() as otlp:
        env = {"OTEL_EXPORTER_OTLP_ENDPOINT": otlp.endpoint, "OTEL_TRACES_SAMPLER": "always_on"}
        url, _ = serve(start, "netapp", real_model_path, env=env)
        with NetAppClient(url, transport="http") as client:
            client.send((media_dir / "dog.jpg").read_bytes())
            assert client.wait_idle(60)
            (result,) = list(client.results(timeout=1))
        spans = otlp.wait_for(lambda spans: {"netapp.frame", "inference"} <= {s.name for s in spans}, timeout_s=30)
    assert {"dog", "bicycle", "car"} <= {d["class_name"] for d in result.detections if d["score"] >= 0.75}
    assert {s.service for s in spans if s.name == "netapp.frame"} == {"netapp"}, spans


def test_netapp_image_is_ready_within_2_s(start, real_model_path):
    """The best of three starts: one start alone measures the other processes on these shared cores as well."""
    times = []
    for _ in range(3):
        times.append(serve(start, "netapp", real_model_path)[1])
        if times[-1] <= READY_S:
            break
    print(f"netapp image: start to /readyz {', '.join(f'{t:.2f}' for t in times)} s")
    assert min(times) <= READY_S, times


def test_runs_as_its_own_user_on_a_read_only_root(built):
    builder, refs = built
    probe = "import os; open('/tmp/ok', 'w').close(); print(os.getuid()); open('/opt/x', 'w')"
    with images.container(builder, refs["netapp"], ["-c", probe], entrypoint=["python3"]) as argv:
        out = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "10001"
    assert "Read-only file system" in out.stderr


@pytest.fixture(scope="module")
def built_webrtc(built) -> str:
    """`netapp-webrtc` (the `webrtc` extra, `--build-arg WEBRTC=1`), added to the refs `start` runs."""
    builder, refs = built
    refs.update(images.build(["netapp-webrtc"], builder))
    return refs["netapp-webrtc"]


def test_webrtc_image_serves_a_robot_over_webrtc(built, built_webrtc, start, real_model_path, media_dir):
    """/camera and POST /webrtc/offer in a cluster: a robot's WebRTC track answered with boxes on its data channel."""
    import cv2

    from netapp.client.webrtc import WebRtcClient

    url, _ = serve(start, "netapp-webrtc", real_model_path)
    with urllib.request.urlopen(f"{url}/camera", timeout=10) as page:
        assert page.status == 200
    picture, results = cv2.imread(str(media_dir / "dog.jpg")), []
    with WebRtcClient(url, ice_addresses=("127.0.0.1",)) as client:
        deadline = time.monotonic() + 60
        while not results and time.monotonic() < deadline:
            client.send(picture)
            time.sleep(0.1)
            results += client.results(timeout=0)
    assert results and {"dog"} <= {d["class_name"] for d in results[-1].detections}, results
    builder, _ = built
    layers = images.layer_sizes(builder, built_webrtc) if builder == "buildah" else []
    if layers:
        print(f"netapp-webrtc: {sum(size for size, _ in layers) / MB:.0f} MB")
        assert sum(size for size, _ in layers) <= WEBRTC_GOAL_MB * MB, layers


def test_tracking_image_tracks(start, real_model_path, media_dir):
    from netapp.client import NetAppClient

    url, _ = serve(start, "netapp-tracking", real_model_path, "--processor", "object-tracking")
    jpeg = (media_dir / "dog.jpg").read_bytes()
    with NetAppClient(url, transport="ws", max_in_flight=1) as client:
        for _ in range(3):
            client.send(jpeg)
            assert client.wait_idle(60)
        results = list(client.results(timeout=1))
    assert any(d.get("track_id") is not None for d in results[-1].detections), results[-1].detections


async def test_control_plane_operator_reconciles_a_netapp(start, tmp_path):
    kmock = pytest.importorskip("kmock", reason="kmock is not installed (pip install '.[test]')")
    kopf = pytest.importorskip("kopf", reason="the operator extra is not installed (pip install '.[operator,test]')")
    from netapp_operator.kube import Kube, login_from_info

    from tests.operator.op_helpers import eventually, netapp, node, nodepool
    from tests.support.kube_emulator import Emulator, declare

    async with Emulator() as emulator, kmock.Server(emulator):
        declare(emulator)
        server = str(emulator.url).rstrip("/")
        kube = tmp_path / "kube"  # readable by the image's user, mounted read-only
        kube.mkdir(mode=0o755)
        (kube / "kubeconfig").write_text(kubeconfig(server))
        (kube / "kubeconfig").chmod(0o644)
        args = ["--log-level", "WARNING", "operator", "--all-namespaces", "--check-interval=0.5"]
        env = {"KUBECONFIG": "/opt/kube/kubeconfig"}
        proc = start("control-plane", args, {str(kube): "/opt/kube"}, env)
        procs = [proc]  # stopped before the emulator: a client still watching holds its shutdown for a minute

        async def login():
            return await login_from_info(kopf.ConnectionInfo(server=server))

        api = Kube(login, manager="image-test")
        try:
            await api.apply(node("edge-1", {"pool": "edge"}, address="192.168.1.10"))
            await api.apply(nodepool("edge", "edge", {"pool": "edge"}))
            await api.apply(netapp("det"))

            async def status_url():
                assert proc.poll() is None, f"the operator exited: {proc.stdout.read()[-3000:]}"
                na = await api.get("NetApp", "default", "det")
                return ((na or {}).get("status") or {}).get("url")

            t0 = time.monotonic()
            assert (await eventually(status_url, timeout=90, what="status.url")).startswith("http://192.168.1.10:")
            print(f"operator: status.url after {time.monotonic() - t0:.1f} s")
            # The middleware, from the same image, serves against the same API.
            port = free_port()
            args = ["middleware", "--backend", "kubernetes", "--host", "127.0.0.1", "--port", str(port)]
            middleware = start("control-plane", args, {str(kube): "/opt/kube"}, env)
            procs.append(middleware)
            ready_s = await asyncio.to_thread(wait_ready, middleware, f"http://127.0.0.1:{port}/healthz")
            print(f"middleware ready after {ready_s:.1f} s")
        finally:
            await api.close()
            for p in procs:
                await asyncio.to_thread(stop, p)


# --- the GPU image (opt-in: a few GB of NVIDIA's wheels, minutes to build cold) ------------------------------------

GPU_IMAGE_ENV = "NETAPP_TEST_GPU_IMAGE"
GPU_GOAL_MB = 3000  # 2823 MB measured (docs/images.md#the-gpu-image): onnxruntime-gpu 303, NVIDIA's wheels 2061


@pytest.fixture(scope="module")
def built_gpu() -> tuple[str, str]:
    if os.environ.get(GPU_IMAGE_ENV) != "1":
        pytest.skip(f"the GPU image is a few GB: {GPU_IMAGE_ENV}=1 builds and runs it")
    reason = _skip_reason()
    if reason:
        pytest.skip(reason)
    builder = images.find_builder()
    return builder, images.build(["gpu"], builder)["gpu"]


def test_gpu_image_loads_the_nvidia_libraries_and_serves_on_the_cpu_without_a_gpu(
    built_gpu, real_model_path, media_dir
):
    """Built from PyPI wheels on the Debian base: `netapp serve` loads CUDA, cuBLAS and cuDNN from the wheels and
    says so; with no GPU here onnxruntime falls back to the CPU, and the netapp serves a detection all the same."""
    from netapp.client import NetAppClient

    builder, ref = built_gpu
    port = free_port()
    args = ["--host", "127.0.0.1", "--port", str(port), "--model", f"/opt/model/{real_model_path.name}"]
    with images.container(builder, ref, args, {str(real_model_path.parent): "/opt/model"}) as argv:
        proc = subprocess.Popen(
            argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True
        )
        try:
            url = f"http://127.0.0.1:{port}"
            wait_ready(proc, f"{url}/readyz", timeout=120)
            with NetAppClient(url, transport="http") as client:
                client.send((media_dir / "dog.jpg").read_bytes())
                assert client.wait_idle(60)
                (result,) = list(client.results(timeout=1))
        finally:
            stop(proc)
    output = proc.stdout.read()
    assert {"dog", "bicycle", "car"} <= {d["class_name"] for d in result.detections if d["score"] >= 0.75}
    [line] = [x for x in output.splitlines() if "GPU libraries:" in x]  # the netapp's log at start
    for library in ("libcudart.so", "libcublas.so", "libcublasLt.so", "libcudnn.so"):
        assert library in line, line
    layers = images.layer_sizes(builder, ref) if builder == "buildah" else []
    if layers:
        assert sum(size for size, _ in layers) <= GPU_GOAL_MB * MB, layers
        assert "/opt/app" in layers[-1][1] and layers[-1][0] <= CODE_LAYER_MB * MB, layers[-1]
