"""The docs hold together: every link and heading they point to exists, every pointer from the code into them
resolves, and every file and name `docs/design.md` gives exists in the code."""

from __future__ import annotations

import ast
import re
import sys
from functools import cache
from pathlib import Path

import pytest

from tests.docs.test_readme import DOC_PAGES as RUN_PAGES
from tests.support.paths import ROOT

# The pages whose links must resolve: the ones whose code runs, and the benchmarks' and the chart's own.
DOC_PAGES = [*RUN_PAGES, ROOT / "bench" / "README.md", ROOT / "charts" / "netapp-toolkit" / "README.md"]
# Where code and configuration may point into the docs (the docs pages themselves are checked as pages).
CODE_PLACES = [
    *("netapp", "operator", "bench", "tools", "charts", "docker", ".ci", "tests/support", "Makefile", "pyproject.toml")
]
CODE_SUFFIXES = {".py", ".yaml", ".yml", ".tpl", ".json", ".toml", ".txt", ".sh", ".Dockerfile", ""}


def rel(path: Path) -> str:
    return str(path.relative_to(ROOT))


# --- markdown: headings and links ---------------------------------------------------------------------------------


def without_code(text: str) -> list[tuple[int, str]]:
    """The lines outside fenced code blocks, numbered from 1, with inline code spans blanked."""
    lines, fenced = [], False
    for number, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if not fenced:
            lines.append((number, re.sub(r"`[^`]*`", "``", line)))
    return lines


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a heading: markup and punctuation dropped, lower case, spaces to hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link's text only
    text = re.sub(r"[^\w\- ]", "", text.strip().lower())
    return text.replace(" ", "-")


@cache
def headings(path: Path) -> dict[str, str]:
    """Anchor -> heading text of a markdown page (a repeated heading gets -1, -2, ... as on GitHub)."""
    anchors: dict[str, str] = {}
    fenced = False
    for line in path.read_text().splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
        match = None if fenced else re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if match:
            slug = github_slug(match.group(1))
            unique, n = slug, 0
            while unique in anchors:
                n += 1
                unique = f"{slug}-{n}"
            anchors[unique] = re.sub(r"[`*]", "", match.group(1))
    return anchors


def test_github_slugs():
    assert github_slug("Links that fail (`resilience.py`)") == "links-that-fail-resiliencepy"
    assert github_slug("Scaling on the netapps' own signal") == "scaling-on-the-netapps-own-signal"
    assert github_slug("Data path: socket -> session -> queue") == "data-path-socket---session---queue"
    assert github_slug("`netapp stream`") == "netapp-stream"


def markdown_links(path: Path) -> list[tuple[int, str]]:
    """(line, target) of every link and image of a page, outside code."""
    return [
        (number, target)
        for number, line in without_code(path.read_text())
        for target in re.findall(r"\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)", line)
    ]


def check_target(source: Path, target: str, base: Path) -> str | None:
    """Why `target` (a path relative to `base`, with an optional #anchor) does not resolve, or None."""
    path_part, _, anchor = target.partition("#")
    path = (base / path_part).resolve() if path_part else source
    if not path.exists():
        return f"{path_part}: no such file"
    if anchor and (path.suffix != ".md" or anchor not in headings(path)):
        return f"#{anchor}: no such heading in {rel(path)}"
    return None


@pytest.mark.parametrize("page", DOC_PAGES, ids=rel)
def test_every_relative_link_resolves(page: Path):
    links = [(n, t) for n, t in markdown_links(page) if not re.match(r"^[a-z]+:", t)]
    broken = [f"{rel(page)}:{n}: {t}: {why}" for n, t in links if (why := check_target(page, t, page.parent))]
    assert not broken, "\n".join(broken)


def test_the_docs_pages_link_each_other():
    readme_links = {target.partition("#")[0] for _, target in markdown_links(ROOT / "README.md")}
    unlisted = [rel(p) for p in (ROOT / "docs").glob("*.md") if rel(p) not in readme_links]
    assert not unlisted, f"the README's index misses {unlisted}"


# --- pointers from the code into the docs ---------------------------------------------------------------------------

# A pointer is a path to a .md file from the repository root, then either #anchor or a "Heading" in quotes.
POINTER = re.compile(r"(?<![\w/.-])((?:[\w.-]+/)*README\.md|docs/[\w./-]+\.md)(?:#([\w-]+)|\s+\"([^\"]+)\")?")


def code_files() -> list[Path]:
    files: list[Path] = []
    for place in CODE_PLACES:
        path = ROOT / place
        candidates = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
        files += [
            p
            for p in candidates
            if (p.suffix in CODE_SUFFIXES or p.name.endswith(".Dockerfile"))
            and p.suffix != ".md"
            and "__pycache__" not in p.parts
            and "node_modules" not in p.parts
        ]
    return files


def code_pointers() -> list[tuple[str, str, str]]:
    """(place, pointer, why it does not resolve or "") for every mention of a README or docs/ in the code."""
    found = []
    for path in code_files():
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        for number, line in enumerate(text.splitlines(), 1):
            line = re.sub(r"https?://\S+", "", line)  # a web address is not ours
            place = f"{rel(path)}:{number}"
            for match in POINTER.finditer(line):
                target, anchor, heading = match.groups()
                why = check_target(ROOT / target, f"{target}#{anchor}" if anchor else target, ROOT) or ""
                if heading and not why:
                    names = set(headings(ROOT / target)) | set(headings(ROOT / target).values())
                    why = "" if heading in names else f'"{heading}": no such heading in {target}'
                found.append((place, match.group(0), why))
            rest = POINTER.sub("", line)
            for bare in re.findall(r"\bREADME\b", rest):
                found.append((place, bare, "a README mention that is not a path to it (README.md#anchor)"))
            for path_ in re.findall(r"(?<![\w/.-])docs/[\w./-]*[\w/-]", rest):
                if not (ROOT / path_).exists():
                    found.append((place, path_, "no such file in docs/"))
    return found


def test_every_pointer_from_the_code_resolves():
    pointers = code_pointers()
    assert len([p for p in pointers if "docs/" in p[1]]) >= 8, "the search finds the code's pointers into docs/"
    broken = [f"{place}: {pointer}: {why}" for place, pointer, why in pointers if why]
    assert not broken, "\n".join(broken)


def test_a_stale_pointer_is_caught(tmp_path, monkeypatch):
    bad = tmp_path / "netapp" / "x.py"
    bad.parent.mkdir()
    bad.write_text(
        '# see docs/security.md#limits and docs/security.md "Limits"\n'
        '# README "Limits and security", docs/security.md#no-such, docs/nowhere.md, docs/benchmarks.md "Nope"\n'
    )
    monkeypatch.setattr(sys.modules[__name__], "CODE_PLACES", ["netapp/x.py"])
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "security.md").write_text("# Security\n\n## Limits\n")
    (tmp_path / "docs" / "benchmarks.md").write_text("# Benchmarks\n")
    headings.cache_clear()
    try:
        whys = [why for _, _, why in code_pointers()]
    finally:
        headings.cache_clear()
    assert whys[:2] == ["", ""]
    assert len([w for w in whys if w]) == 4, whys


# --- docs/design.md names files and code that exist -----------------------------------------------------------------

DESIGN = ROOT / "docs" / "design.md"
PATH_LIKE = re.compile(r"^[\w./-]+(/|\.(py|js|yaml|html|css|md))$")
NAME_LIKE = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)?(\(\))?$")


def backticked(text: str) -> list[str]:
    return re.findall(r"`([^`]+)`", text)


def resolve_path(token: str, near: list[Path]) -> list[Path]:
    """The files a design.md path stands for: from the root, from operator/, or beside the row's other paths."""
    bases = [ROOT, ROOT / "operator", *near]
    for base in bases:
        path = base / token
        if path.exists():
            if not path.is_dir():
                return [path]
            # bytecode caches are not what a design row names, and do not decode as text
            return sorted(p for p in path.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    for base in near:  # a bare file name in a folder the row names, e.g. `ui.js` in `netapp/server/ui/static/`
        if base.is_dir():
            hits = sorted(p for p in base.rglob(token) if "__pycache__" not in p.parts)
            if hits:
                return hits
    return []


class Defined:
    """What a Python file defines: top-level names, each class's members, and its string literals."""

    def __init__(self, path: Path):
        self.names: set[str] = set()
        self.members: dict[str, set[str]] = {}
        self.strings: set[str] = set()
        self.text = path.read_text()
        if path.suffix != ".py":
            return
        tree = ast.parse(self.text)
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                self.strings.add(node.value)
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                self.names.add(node.name)
            if isinstance(node, ast.ClassDef):
                members = self.members.setdefault(node.name, set())
                for item in ast.walk(node):
                    if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
                        members.add(item.name)
                    elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                        members.add(item.target.id)
                    elif isinstance(item, ast.Assign):
                        members.update(t.id for t in item.targets if isinstance(t, ast.Name))
                    if isinstance(item, ast.Attribute) and isinstance(item.ctx, ast.Store):
                        members.add(item.attr)  # self.x = ...
            elif isinstance(node, ast.Assign):
                self.names.update(t.id for t in node.targets if isinstance(t, ast.Name))


@cache
def defined(path: Path) -> Defined:
    return Defined(path)


def name_exists(name: str, files: list[Path]) -> bool:
    """`function`, `Class`, `Class.member` or `module.function` defined in one of `files` (or, for a word of the
    wire such as an event name, a string literal there)."""
    name = name.removesuffix("()")
    owner, _, member = name.rpartition(".")
    for path in files:
        found = defined(path)
        if path.suffix != ".py" and re.search(rf"\b{re.escape(name)}\b", found.text):
            return True
        if not owner and (name in found.names or name in found.strings):
            return True
        if not owner and any(name in members for members in found.members.values()):
            return True
        if owner and member in found.members.get(owner, set()):
            return True
        if owner and path.stem == owner and member in found.names:
            return True
    return False


def design_rows() -> list[tuple[int, list[str]]]:
    """(line, cells) of design.md's table rows, and each paragraph outside the tables as a one-cell row."""
    rows = []
    for number, line in enumerate(DESIGN.read_text().splitlines(), 1):
        if line.startswith("|") and not re.match(r"^\|[-| ]+\|$", line) and not line.startswith("| step"):
            rows.append((number, line.strip("|").split(" | ")))
        elif line and not line.startswith(("|", "#")):
            rows.append((number, [line]))
    return rows


def design_problems() -> list[str]:
    rows = design_rows()
    all_files: list[Path] = []
    row_files: dict[int, list[Path]] = {}
    problems = []
    for number, cells in rows:
        files: list[Path] = []
        for token in [t for cell in cells for t in backticked(cell) if PATH_LIKE.match(t)]:
            near = sorted({folder for p in files for folder in p.parents if ROOT in folder.parents})
            hits = resolve_path(token, near)
            if not hits:
                problems.append(f"docs/design.md:{number}: `{token}`: no such file or folder")
            files += hits
        row_files[number] = files + modules_named(cells)
        all_files += files
    python_files = sorted(set(all_files))
    for number, cells in rows:
        names = [t for cell in cells[1:] or cells for t in backticked(cell) if NAME_LIKE.match(t) and not t.isupper()]
        for name in names:
            if "." in name.removesuffix("()") and PATH_LIKE.match(name):
                continue
            if not (name_exists(name, row_files[number]) or name_exists(name, python_files) or module_member(name)):
                problems.append(f"docs/design.md:{number}: `{name}`: defined in none of the files it names")
    return problems


def modules_named(cells: list[str]) -> list[Path]:
    """The project's modules a row names as `module.function` (e.g. `spec.parse`: operator/netapp_operator/spec.py)."""
    owners = {t.partition(".")[0] for cell in cells for t in backticked(cell) if re.match(r"^[a-z_]+\.\w+", t)}
    return [p for owner in owners for base in ("netapp", "operator") for p in (ROOT / base).rglob(f"{owner}.py")]


def module_member(name: str) -> bool:
    """`module.function` where the module sits in one of the project's packages (e.g. `spec.parse`)."""
    owner, _, member = name.removesuffix("()").rpartition(".")
    if not owner:
        return False
    modules = [p for base in ("netapp", "operator") for p in (ROOT / base).rglob(f"{owner}.py")]
    return any(member in defined(p).names for p in modules)


def test_design_names_files_and_code_that_exist():
    problems = design_problems()
    assert not problems, "\n".join(problems)


def test_design_check_catches_a_wrong_name(monkeypatch, tmp_path):
    page = tmp_path / "design.md"
    page.write_text(
        DESIGN.read_text()
        + "\n| a wrong row | `netapp/server/pipeline.py` | `Pipeline.no_such_method`, `no_such_function`;"
        + " `netapp/nowhere.py` |\n"
    )
    monkeypatch.setattr(sys.modules[__name__], "DESIGN", page)
    problems = design_problems()
    assert any("`Pipeline.no_such_method`" in p for p in problems), problems
    assert any("`no_such_function`" in p for p in problems), problems
    assert any("`netapp/nowhere.py`" in p for p in problems), problems


# --- the NetApps the docs show are valid -----------------------------------------------------------------------------


def test_the_netapps_the_docs_show_are_valid():
    import yaml
    from netapp_operator.constants import API_VERSION
    from netapp_operator.spec import parse

    shown = []
    for page in DOC_PAGES:
        for block in re.findall(r"```yaml\n(.*?)```", page.read_text(), flags=re.S):
            for doc in yaml.safe_load_all(block):
                if isinstance(doc, dict) and doc.get("kind") == "NetApp":
                    shown.append((rel(page), doc))
    assert shown, "the README shows a NetApp"
    for page, doc in shown:
        assert doc["apiVersion"] == API_VERSION, page
        assert parse(doc["spec"]).problems == (), (page, parse(doc["spec"]).problems)
