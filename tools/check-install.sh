#!/usr/bin/env bash
# `pip install .` with no extras into a throwaway virtual environment, then what a new user runs first: the CLI's
# help, and importing the robot client, the operator and the middleware. Proves they need no test extra (and no test
# scaffolding) at import. Built from a copy of the working tree (tracked and untracked files git does not ignore),
# so no build/ or *.egg-info is left here and no stale build output slips into the wheel.
#
#   make check-install          (CI runs it before `make test`)
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
mkdir "$tmp/src"
git ls-files -z --cached --others --exclude-standard | while IFS= read -r -d '' f; do
  [ -e "$f" ] && printf '%s\0' "$f"  # not the tracked files deleted in the working tree
done | tar --null -T - -cf - | tar -xf - -C "$tmp/src"
"$PYTHON" -m venv "$tmp/venv"
"$tmp/venv/bin/python" -m pip install -q "$tmp/src"
cd "$tmp"  # away from the checkout, so that the installed packages are the ones imported
"$tmp/venv/bin/netapp" --help >/dev/null
"$tmp/venv/bin/python" -c "import netapp.client, netapp_operator, netapp_middleware"
# the package data a robot reads at run time came along
"$tmp/venv/bin/python" -c "from netapp.accuracy import load_profile; assert load_profile('yolox_nano')"
echo "check-install: pip install . (no extras): netapp --help, the imports and the package data succeed"
