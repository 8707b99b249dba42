"""Helpers for the chart and packaging tests: paths, helm runs, and the tool fetcher (cached in .tools/)."""

from __future__ import annotations

import pathlib
import subprocess
from typing import Any

import yaml

from tests.support.paths import ROOT
from tools.fetch_tools import ensure  # noqa: F401 (re-exported for the chart tests)

CHART = ROOT / "charts" / "netapp-toolkit"


def run(*args: Any, check: bool = True) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(a) for a in args], capture_output=True, text=True, check=check, timeout=120)


def template(helm: pathlib.Path, *values: pathlib.Path, namespace: str = "netapp-system") -> list[dict[str, Any]]:
    """Every object `helm template` renders (CRDs included), as dicts."""
    flags = [f for v in values for f in ("--values", v)]
    out = run(helm, "template", "netapp-toolkit", CHART, "--namespace", namespace, "--include-crds", *flags).stdout
    return [d for d in yaml.safe_load_all(out) if d]
