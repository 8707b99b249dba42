"""Dockerfiles: linted with hadolint, installing exactly the pyproject extras the tests install."""

from __future__ import annotations

import re

import pytest
import tomllib

from tests.chart.chart_helpers import ROOT, run

DOCKERFILES = sorted((ROOT / "docker").glob("*.Dockerfile"))


@pytest.mark.parametrize("path", DOCKERFILES, ids=lambda p: p.name)
def test_hadolint(hadolint, path):
    result = run(hadolint, "--failure-threshold", "info", path, check=False)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize(
    "path, extras",
    [
        # the netapp: core and server in its dependency layer (h264 and webrtc with build args); its tracking target
        # adds the tracker's; its GPU target the server's less onnxruntime, with gpu (and tensorrt with a build arg).
        # Every image has `tracing`, so that tracing turned on in the chart traces rather than logging the install hint,
        # and `broker`, so that a NetApp's spec.publish publishes (docs/broker.md).
        (
            "netapp.Dockerfile",
            {"server", "tracing", "broker", "h264", "webrtc", "tracking", "tracking-runtime", "gpu", "tensorrt"},
        ),
        ("control-plane.Dockerfile", {"operator", "middleware", "tracing"}),
    ],
)
def test_images_install_from_pyproject(path, extras):
    text = (ROOT / "docker" / path).read_text()
    instructions = "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("#"))
    instructions = re.sub(r"\$\{\w+:\+([\w-]+)\}", r"\1", instructions)  # an extra a build arg adds: ${H264:+h264}
    instructions = re.sub(r"\\\n\s*", " ", instructions)  # continued lines as one
    installs = [set(i.split(",")) for i in re.findall(r"pip install '\.\[([a-z,-]+)\]'", instructions)]
    # docker/requirements.py lists an extra's requirements from pyproject.toml for `pip install -r`
    found = re.findall(r"requirements\.py \S+ (?:--[\w=-]+ )*([a-z0-9 -]+?) \\?\s*>", instructions)
    installs += [set(i.split()) for i in found]
    assert set().union(*installs) == extras
    declared = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"])
    assert extras <= declared
    if "tracking" in extras:  # and `trackers` without the opencv-python it asks for, as the Makefile installs it
        from netapp.builtin_processors import TRACKERS_REQUIREMENT

        assert f"--no-deps '{TRACKERS_REQUIREMENT}'" in instructions
        assert f"TRACKERS := {TRACKERS_REQUIREMENT}" in (ROOT / "Makefile").read_text()
    assert "USER 10001:10001" in text  # non-root
    assert "MODEL_URL" not in text or 'if [ -n "$MODEL_URL" ]' in text  # a model only when a build arg asks


def test_the_gpu_target_replaces_onnxruntime_with_its_cuda_build():
    """The GPU image installs the server's requirements without onnxruntime (onnxruntime-gpu is the same module),
    on the Debian base the other images use, and runs `netapp serve` (which loads the NVIDIA libraries)."""
    text = (ROOT / "docker" / "netapp.Dockerfile").read_text()
    assert re.search(r"--without=onnxruntime \\?\s*server tracing gpu", text)
    stage = text[text.index("FROM runtime AS netapp-gpu") :].split("\n\n")[0]
    assert "COPY --from=gpu-deps /opt/venv /opt/venv" in stage
    assert "FROM runtime AS netapp-gpu" in stage and stage.rstrip().endswith("USER 10001:10001")
    assert "nvidia/cuda" not in text  # no registry base: the CUDA libraries come from wheels
