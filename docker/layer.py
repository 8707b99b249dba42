"""Install into a venv, then move what the install added into its own folder, so it becomes its own image layer.

    python3 layer.py VENV FOLDER PIP_ARGS...

`pip --python VENV/bin/python install PIP_ARGS` runs (pip itself stays outside the image); the new entries of the
venv's site-packages move to FOLDER and the new scripts to FOLDER/bin, where the venv finds them through the
`netapp-layers.pth` the dependency stage writes. The install must add only: a package it upgraded or removed in the
venv fails the build (that layer would be stale).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path


def site_packages(venv: Path) -> Path:
    (path,) = venv.glob("lib/python3*/site-packages")
    return path


def installed(venv: Path) -> set[str]:
    out = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python"), "freeze", "--all"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return set(out.splitlines())


def entries(venv: Path) -> set[Path]:
    """What an install adds to: site-packages, its __pycache__ (top-level modules' bytecode) and bin."""
    site = site_packages(venv)
    return {p for d in (site, site / "__pycache__", venv / "bin") if d.is_dir() for p in d.iterdir()}


def main(venv: Path, folder: Path, pip_args: list[str]) -> None:
    site, before, before_dists = site_packages(venv), entries(venv), installed(venv)
    python = str(venv / "bin" / "python")
    subprocess.run([sys.executable, "-m", "pip", "--python", python, "install", *pip_args], check=True)
    changed = before_dists - installed(venv)
    if changed:
        raise SystemExit(f"the install changed what the venv had: {sorted(changed)}")
    for path in sorted(entries(venv) - before):
        if not path.exists():
            continue  # inside a folder that already moved
        target = folder / (path.relative_to(site) if path.is_relative_to(site) else path.relative_to(venv))
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(path, target)


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3:])
