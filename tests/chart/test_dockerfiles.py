"""Dockerfiles: linted with hadolint, installing exactly the pyproject extras the tests install."""

from __future__ import annotations

import importlib.metadata
import re

import pytest

from tests.chart.chart_helpers import ROOT, run

DOCKERFILES = sorted((ROOT / "docker").glob("*.Dockerfile"))


@pytest.mark.parametrize("path", DOCKERFILES, ids=lambda p: p.name)
def test_hadolint(hadolint, path):
    result = run(hadolint, "--failure-threshold", "info", path, check=False)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize(
    "path, extras",
    [
        # the netapp: core and server in its dependency layer (h264 with a build arg); its tracking target adds the
        # tracker's
        ("netapp.Dockerfile", {"server", "h264", "tracking", "tracking-runtime"}),
        ("netapp-gpu.Dockerfile", {"server", "tracking"}),
        ("control-plane.Dockerfile", {"operator", "middleware"}),
    ],
)
def test_images_install_from_pyproject(path, extras):
    text = (ROOT / "docker" / path).read_text()
    instructions = "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("#"))
    instructions = re.sub(r"\$\{\w+:\+([\w-]+)\}", r"\1", instructions)  # an extra a build arg adds: ${H264:+h264}
    installs = [set(i.split(",")) for i in re.findall(r"pip install '\.\[([a-z,-]+)\]'", instructions)]
    # docker/requirements.py lists an extra's requirements from pyproject.toml for `pip install -r`
    installs += [set(i.split()) for i in re.findall(r"requirements\.py \S+ (?:--\w+ )*([a-z0-9 -]+?) >", instructions)]
    assert set().union(*installs) == extras
    declared = set(importlib.metadata.metadata("netapp-toolkit").get_all("Provides-Extra") or [])
    assert extras <= declared
    if "tracking" in extras:  # and `trackers` without the opencv-python it asks for, as the Makefile installs it
        from netapp.builtin_processors import TRACKERS_REQUIREMENT

        assert f"--no-deps '{TRACKERS_REQUIREMENT}'" in instructions
        assert f"TRACKERS := {TRACKERS_REQUIREMENT}" in (ROOT / "Makefile").read_text()
    assert "USER 10001:10001" in text  # non-root
    assert "MODEL_URL" not in text or 'if [ -n "$MODEL_URL" ]' in text  # a model only when a build arg asks


def test_gpu_provider_choice_is_reported():
    import subprocess
    import sys

    result = subprocess.run(
        [sys.executable, str(ROOT / "docker" / "ort_provider.py")],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    assert result.stdout.strip() in ("CPUExecutionProvider", "CUDAExecutionProvider,CPUExecutionProvider")
    assert "provider" in result.stderr
