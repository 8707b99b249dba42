#!/usr/bin/env python3
"""Render manifests/ from the Helm chart, the single source of truth: `make manifests`.

    python -m tools.render_manifests           # write manifests/00-crds.yaml and manifests/netapp-toolkit.yaml
    python -m tools.render_manifests --check   # exit 1 if manifests/ differs from the chart (what the test does)

`kubectl apply -f manifests/` then creates what `helm install netapp-toolkit charts/netapp-toolkit -n netapp-system
--create-namespace` creates with the default values.
"""

from __future__ import annotations

import pathlib
import subprocess
import sys

from tools.fetch_tools import ensure

ROOT = pathlib.Path(__file__).resolve().parents[1]
CHART = ROOT / "charts" / "netapp-toolkit"
OUT = ROOT / "manifests"
RELEASE, NAMESPACE = "netapp-toolkit", "netapp-system"
TOKEN_KEY_SECRET = f"{RELEASE}-middleware-token-key"
ROLLOUT_TOKEN_SECRET = f"{RELEASE}-operator-rollout-token"  # the same, for the operator's model rollouts
HEADER = "# Generated from charts/netapp-toolkit by `make manifests` (tools/render_manifests.py): do not edit.\n"


def render(helm: pathlib.Path) -> dict[str, str]:
    """File name -> content of every generated file under manifests/."""
    crds = [p.read_text().strip() + "\n" for p in sorted((CHART / "crds").glob("*.yaml"))]
    templates = subprocess.run(
        [str(helm), "template", RELEASE, str(CHART), "--namespace", NAMESPACE, "--set", "createNamespace=true"]
        # The token key Secret is drawn at install time, which `kubectl apply` cannot do: it is created once
        # by hand (docs/kubernetes.md#plain-kubectl), under the name the chart would give it, so the
        # Deployment is the same as helm's.
        + ["--set", f"middleware.tokenKeySecret={TOKEN_KEY_SECRET}"]
        + ["--set", f"operator.rollouts.tokenSecret={ROLLOUT_TOKEN_SECRET}"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return {
        "00-crds.yaml": HEADER + "---\n".join(crds),
        "netapp-toolkit.yaml": HEADER + templates.lstrip("-\n"),
    }


def main(argv: list[str]) -> int:
    helm = ensure("helm")
    if helm is None:
        print("helm is unavailable (see tools/fetch_tools.py)", file=sys.stderr)
        return 2
    files = render(helm)
    if "--check" in argv:
        stale = [name for name, text in files.items() if not (OUT / name).exists() or (OUT / name).read_text() != text]
        for name in stale:
            print(f"manifests/{name} differs from the chart: run `make manifests`", file=sys.stderr)
        return 1 if stale else 0
    for name, text in files.items():
        (OUT / name).write_text(text)
        print(f"wrote manifests/{name}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
