"""The chart's README: `helm show readme` prints it, its values table is generated from values.schema.json and
up to date, and every value in the schema has a description."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import yaml

from tests.chart.chart_helpers import CHART, run
from tools import chart_readme

SCHEMA = json.loads((CHART / "values.schema.json").read_text())


def value_nodes(node: dict[str, Any], path: str) -> Iterator[tuple[str, dict[str, Any]]]:
    """Every property of the schema, its definitions included, with its path."""
    for name, child in node.get("properties", {}).items():
        yield f"{path}.{name}", child
        yield from value_nodes(child, f"{path}.{name}")
    if isinstance(node.get("items"), dict):
        yield from value_nodes(node["items"], f"{path}[]")


def test_every_value_has_a_description():
    nodes = list(value_nodes(SCHEMA, ""))
    for name, definition in SCHEMA["definitions"].items():
        nodes += [(f"#{name}", definition), *value_nodes(definition, f"#{name}")]
    missing = [path for path, node in nodes if not node.get("description")]
    assert len(nodes) > 60 and not missing, missing


def test_the_values_table_is_up_to_date():
    readme = (CHART / "README.md").read_text()
    values = yaml.safe_load((CHART / "values.yaml").read_text())
    assert chart_readme.render(readme, SCHEMA, values) == readme, "run: python tools/chart_readme.py"
    assert "| `operator.failoverGraceSeconds` | number | `30` | how long a pool" in readme


def test_a_stale_table_is_caught(tmp_path, monkeypatch):
    stale = tmp_path / "README.md"
    stale.write_text((CHART / "README.md").read_text().replace("install the operator", "install it"))
    for name in ("values.schema.json", "values.yaml"):
        (tmp_path / name).write_text((CHART / name).read_text())
    monkeypatch.setattr(chart_readme, "CHART", tmp_path)
    assert chart_readme.main(["--check"]) == 1
    assert chart_readme.main([]) == 0 and chart_readme.main(["--check"]) == 0


def test_helm_show_readme_prints_it(helm):
    shown = run(helm, "show", "readme", CHART).stdout
    assert shown.startswith("# netapp-toolkit chart") and "are **not published**" in shown
