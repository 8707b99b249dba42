"""No import cycles inside the project's packages (`netapp`, `netapp_operator`, `netapp_middleware`), and no import
from a lower layer to a higher one (`test_layers_import_only_downwards`).

Every module is parsed with `ast` (nothing is imported) and every import counts: at module level, inside functions
and under `if TYPE_CHECKING:`, because each is a dependency a reader has to follow. Relative imports are resolved,
and `from pkg import name` depends on the submodule `pkg.name` when there is one, else on `pkg` (its `__init__`).
`import a.b.c` depends on `a.b.c`; the parent packages it also runs are not counted, so a package `__init__` that
imports its own submodule is fine as long as that submodule does not import the package back.
"""

from __future__ import annotations

import ast
from collections import deque
from pathlib import Path

import pytest

from tests.support.paths import ROOT

# Each package's directory and the folder it is imported from (pyproject.toml's packages.find).
PACKAGES = {"netapp": ROOT, "netapp_operator": ROOT / "operator", "netapp_middleware": ROOT / "operator"}

Graph = dict[str, dict[str, int]]  # module -> {imported module: first line that imports it}


def module_files(packages: dict[str, Path]) -> dict[str, Path]:
    """Every module of the packages by dotted name (a package by its own name, for its `__init__.py`)."""
    modules = {}
    for package, base in packages.items():
        for path in sorted((base / package).rglob("*.py")):
            parts = path.relative_to(base).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def imports(tree: ast.AST, module: str, is_package: bool, modules: set[str]) -> dict[str, int]:
    """The project modules `module` imports, each with the first line that does; relative imports resolved."""
    found: dict[str, int] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                package = module if is_package else module.rpartition(".")[0]
                for _ in range(node.level - 1):
                    package = package.rpartition(".")[0]
                base = f"{package}.{base}" if base else package
            # `from base import name` imports the submodule base.name when there is one, else from base itself.
            names = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        else:
            continue
        for name in names:
            if name in modules and name != module:
                found[name] = min(found.get(name, node.lineno), node.lineno)
    return found


def import_graph(packages: dict[str, Path]) -> tuple[Graph, dict[str, Path]]:
    """module -> the project modules it imports (third-party and standard-library imports left out)."""
    modules = module_files(packages)
    graph = {
        module: imports(ast.parse(path.read_text(), str(path)), module, path.name == "__init__.py", set(modules))
        for module, path in modules.items()
    }
    return graph, modules


def cycles(graph: Graph) -> list[list[str]]:
    """The shortest cycle through each module that lies on one, each cycle once (rotated to start at its least
    module), so that a failure reads as a chain."""
    found = set()
    for start in sorted(graph):
        previous: dict[str, str] = {}  # breadth-first from start back to start: the shortest chain
        queue = deque([start])
        while queue and start not in previous:
            node = queue.popleft()
            for target in sorted(graph.get(node, {})):
                if target not in previous:
                    previous[target] = node
                    queue.append(target)
        if start in previous:
            chain = [previous[start]]
            while chain[-1] != start:
                chain.append(previous[chain[-1]])
            chain.reverse()  # start, ..., the module that imports start
            least = chain.index(min(chain))
            found.add(tuple(chain[least:] + chain[:least]))
    return [list(cycle) for cycle in sorted(found)]


def describe(cycle: list[str], graph: Graph, modules: dict[str, Path]) -> str:
    """`a (a.py:3) -> b (b.py:7) -> a`: each step with the file and line of its import."""
    steps = []
    for module, target in zip(cycle, cycle[1:] + cycle[:1], strict=True):
        path = modules[module]
        shown = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
        steps.append(f"{module} ({shown}:{graph[module][target]})")
    return " -> ".join(steps + [cycle[0]])


def test_no_import_cycles_in_the_packages() -> None:
    graph, modules = import_graph(PACKAGES)
    assert len(modules) > 20, f"found only {len(modules)} modules: are PACKAGES' directories right?"
    found = [describe(cycle, graph, modules) for cycle in cycles(graph)]
    if found:
        pytest.fail(
            f"{len(found)} import cycle(s); break each (move what both sides need into a module of its own):\n"
            + "\n".join(found),
            pytrace=False,
        )


def write(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_the_checker_finds_cycles_through_every_kind_of_import(tmp_path: Path) -> None:
    write(
        tmp_path,
        {
            "pkg/__init__.py": "from .api import run\nVERSION = 1\n",  # a package importing its submodule: fine
            "pkg/api.py": "from pkg import util\n",  # `from pkg import submodule` depends on util, not on pkg
            "pkg/util.py": "import json\n",
            "pkg/sub/__init__.py": "",
            "pkg/sub/a.py": "def f():\n    from ..sub import b\n",  # inside a function, relative, two levels
            "pkg/sub/b.py": "import pkg.sub.c\n",
            "pkg/sub/c.py": "from . import a\n",
            "pkg/back.py": "from pkg import VERSION\n",  # a name from pkg's __init__: depends on pkg
            "pkg/front.py": "from . import back\n",
        },
    )
    graph, modules = import_graph({"pkg": tmp_path})
    assert graph["pkg.api"] == {"pkg.util": 1}
    assert cycles(graph) == [["pkg.sub.a", "pkg.sub.b", "pkg.sub.c"]]
    sub = tmp_path / "pkg" / "sub"
    assert describe(["pkg.sub.a", "pkg.sub.b", "pkg.sub.c"], graph, modules) == (
        f"pkg.sub.a ({sub}/a.py:2) -> pkg.sub.b ({sub}/b.py:1) -> pkg.sub.c ({sub}/c.py:1) -> pkg.sub.a"
    )

    write(tmp_path, {"pkg/__init__.py": "from .api import run\nfrom . import front\n"})  # front -> back -> pkg
    graph, _ = import_graph({"pkg": tmp_path})
    assert ["pkg", "pkg.front", "pkg.back"] in cycles(graph)


def within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def imports_across(graph: Graph, importers: str, imported: str) -> list[str]:
    """`module -> target` for each module in package `importers` that imports one in package `imported`."""
    return sorted(
        f"{module} -> {target}"
        for module, targets in graph.items()
        if within(module, importers)
        for target in targets
        if within(target, imported)
    )


# The layers, top down: the entry point (netapp.cli) -> the applications (netapp.apps) -> the netapp (netapp.server)
# and the robot's libraries (netapp.ros over netapp.client) -> the models (netapp.models) -> what every side shares
# (netapp.protocol, netapp.frame, netapp.results, netapp.accuracy, ...). Each rule counts every import, lazy or not.
@pytest.mark.parametrize(
    ("importers", "imported", "why"),
    [
        ("netapp.sdk", "netapp.server", "the SDK is the contract a processor is written against, nothing more"),
        ("netapp.client", "netapp.server", "a robot runs the client without the server's dependencies"),
        ("netapp.client", "netapp.ros", "the client library is below ROS: the ROS bridge and recorders use it"),
        ("netapp.client", "netapp.models", "the client library runs on a robot without the model code"),
        ("netapp.client", "netapp.apps", "the applications use the client library, not the other way round"),
        ("netapp.models", "netapp.client", "a model knows no robot (profiles: netapp.accuracy, shared)"),
        ("netapp.models", "netapp.server", "a model knows no server (where it comes from: netapp.models.source)"),
        ("netapp.models", "netapp.apps", "the applications use the models, not the other way round"),
        ("netapp.server", "netapp.client", "`netapp serve` imports no robot client"),
        ("netapp.server", "netapp.apps", "`netapp serve` imports no application"),
        ("netapp.ros", "netapp.apps", "the ROS library is below the applications (`netapp ros2` is netapp.apps.ros2)"),
        ("netapp.ros", "netapp.server", "ROS tools run on a robot, without the server"),
        ("netapp.server.pipeline", "netapp.server.ui", "the live view observes the data path, it is not part of it"),
        ("netapp.server.pipeline", "netapp.server.rollout", "a rollout rides along the pipeline as its InferenceHook"),
        ("netapp.server.settings", "netapp.server", "Settings holds plain values: it imports no feature of the netapp"),
        ("netapp.server.http", "netapp.server.pipeline", "HTTP routes reach the pipeline through the dataplane"),
        ("netapp.server.sio", "netapp.server.pipeline", "Socket.IO handlers reach the pipeline through the dataplane"),
    ],
)
def test_layers_import_only_downwards(importers: str, imported: str, why: str) -> None:
    graph, _ = import_graph(PACKAGES)
    assert any(within(m, importers) for m in graph), f"no module {importers}: is the layout as this test expects?"
    assert any(within(m, imported) for m in graph), f"no module {imported}: is the layout as this test expects?"
    assert imports_across(graph, importers, imported) == [], why


def test_nothing_imports_the_applications_but_the_entry_point() -> None:
    """netapp.apps is the top layer: only the `netapp` entry point (netapp/cli.py, by module name) reaches it."""
    graph, _ = import_graph(PACKAGES)
    edges = [
        f"{module} -> {target}"
        for module, targets in graph.items()
        if not within(module, "netapp.apps") and module != "netapp.cli"
        for target in targets
        if within(target, "netapp.apps")
    ]
    assert edges == []


def test_a_lazy_import_across_a_layer_counts(tmp_path: Path) -> None:
    """An import inside a function, relative or absolute, is a dependency as much as one at the top of the file."""
    write(
        tmp_path,
        {
            "pkg/__init__.py": "",
            "pkg/low/__init__.py": "",
            "pkg/low/a.py": "def f():\n    from ..high import b\n",
            "pkg/low/c.py": "class C:\n    def g(self):\n        import pkg.high.b\n",
            "pkg/high/__init__.py": "",
            "pkg/high/b.py": "from pkg.low import a\n",
        },
    )
    graph, _ = import_graph({"pkg": tmp_path})
    assert imports_across(graph, "pkg.low", "pkg.high") == ["pkg.low.a -> pkg.high.b", "pkg.low.c -> pkg.high.b"]
    assert imports_across(graph, "pkg.high", "pkg.low") == ["pkg.high.b -> pkg.low.a"]
