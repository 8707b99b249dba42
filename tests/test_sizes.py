"""No source file grows past what a reader takes in at once: no `.py` file under the project's code, benchmarks,
tools and tests over MAX_LINES, and the robot's facade, `NetAppClient`, at most FACADE_LINES (it wires its parts,
`netapp/client/assembly.py`, and does no work of its own). A file that grows past it is split along its ideas."""

from __future__ import annotations

from pathlib import Path

from tests.support.paths import ROOT

PLACES = ("netapp", "operator", "bench", "tools", "tests")
MAX_LINES = 500
FACADE = ROOT / "netapp" / "client" / "netapp_client.py"
FACADE_LINES = 300


def line_count(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def oversized(root: Path, places: tuple[str, ...], limit: int) -> list[str]:
    """`path: lines` of each `.py` file under `places` (below `root`) longer than `limit` lines, longest first."""
    files = [
        p
        for place in places
        for p in (root / place).rglob("*.py")
        if not {"__pycache__", "node_modules", ".venv"} & set(p.relative_to(root).parts)
    ]
    sizes = sorted(((line_count(p), p) for p in files), reverse=True)
    return [f"{p.relative_to(root)}: {n} lines" for n, p in sizes if n > limit]


def test_no_source_file_is_over_its_limit():
    offenders = oversized(ROOT, PLACES, MAX_LINES)
    assert not offenders, f"over {MAX_LINES} lines (split each along its ideas): " + ", ".join(offenders)


def test_the_robot_facade_stays_a_facade():
    lines = line_count(FACADE)
    assert lines <= FACADE_LINES, f"{FACADE.relative_to(ROOT)}: {lines} lines, over {FACADE_LINES}"


def test_the_size_check_names_its_offenders(tmp_path):
    (tmp_path / "netapp" / "deep").mkdir(parents=True)
    (tmp_path / "netapp" / "deep" / "long.py").write_text("x = 1\n" * 501)
    (tmp_path / "netapp" / "short.py").write_text("x = 1\n" * 500)
    (tmp_path / "netapp" / "notes.md").write_text("line\n" * 900)
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "longer.py").write_text("x = 1\n" * 700)
    assert oversized(tmp_path, ("netapp", "tests"), 500) == [
        "tests/longer.py: 700 lines",
        "netapp/deep/long.py: 501 lines",
    ]
