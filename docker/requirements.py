"""Print the requirements of pyproject.toml's extras, one a line, for `pip install -r` in an image build.

    python3 requirements.py PYPROJECT [--core] [--direct] [--without=NAME,...] EXTRA...

`--core` adds the project's own `dependencies`; self-references (`netapp-toolkit[x]`) are followed unless `--direct`
(then only the extras' own entries are printed, for a `pip install --no-deps`); `--without` leaves out the named
distributions (`--without=onnxruntime` for the GPU build, whose `onnxruntime-gpu` provides the same module). An
image build installs its dependencies from this list before it copies the code, so a change to the code or the
version rebuilds no dependency layer. The standard library only: it runs in the bare base image.
"""

from __future__ import annotations

import re
import sys

import tomllib


def requirements(
    project: dict, extras: list[str], core: bool = False, direct: bool = False, without: frozenset[str] = frozenset()
) -> list[str]:
    """The requirement strings of `extras` (and the core dependencies with `core`), in order, without repeats, less
    the distributions named in `without`."""
    name = project["name"]
    optional = project.get("optional-dependencies", {})
    out: list[str] = list(project.get("dependencies", [])) if core else []
    pending = list(extras)
    seen: set[str] = set()
    while pending:
        extra = pending.pop(0)
        if extra in seen:
            continue
        if extra not in optional:
            raise SystemExit(f"no extra {extra!r} in pyproject.toml (it has: {', '.join(sorted(optional))})")
        seen.add(extra)
        for req in optional[extra]:
            own = re.fullmatch(rf"{re.escape(name)}\[([\w,-]+)\]", req.replace(" ", ""))
            if own:
                if not direct:
                    pending.extend(own.group(1).split(","))
            else:
                out.append(req)
    kept = [r for r in out if re.match(r"[A-Za-z0-9._-]+", r).group(0).lower() not in without]
    return list(dict.fromkeys(kept))


def main(argv: list[str]) -> None:
    flags = {a for a in argv if a.startswith("--") and "=" not in a}
    without = frozenset(n.lower() for a in argv if a.startswith("--without=") for n in a.split("=", 1)[1].split(","))
    path, *extras = [a for a in argv if not a.startswith("--")]
    with open(path, "rb") as f:
        project = tomllib.load(f)["project"]
    found = requirements(project, extras, core="--core" in flags, direct="--direct" in flags, without=without)
    print("\n".join(found))


if __name__ == "__main__":
    main(sys.argv[1:])
