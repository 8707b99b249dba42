"""What the monitoring tests share: the chart's rules rendered by helm (the one copy, files/rules.yaml), and Debian's
Prometheus programs, each skipped with the install hint where absent."""

from __future__ import annotations

import pathlib
import shutil
from typing import Any

import pytest
import yaml

from tests.chart.chart_helpers import template

INSTALL_HINT = "apt-get install prometheus prometheus-alertmanager (make system-deps)"


def program(name: str) -> str:
    """The path of a Debian Prometheus program (promtool, prometheus, prometheus-alertmanager), or a skip."""
    path = shutil.which(name)
    if path is None:
        pytest.skip(f"{name} is not installed: {INSTALL_HINT}")
    return path


def render_rules(helm: pathlib.Path, directory: pathlib.Path, rules: dict[str, Any] | None = None) -> pathlib.Path:
    """The chart's PrometheusRule, its values under monitoring.rules overridden by `rules`, as a Prometheus rule
    file `directory`/rules.yaml."""
    values = directory / "rules-values.yaml"
    values.write_text(yaml.safe_dump({"monitoring": {"rules": {"enabled": True, **(rules or {})}}}))
    [rule] = [o for o in template(helm, values) if o["kind"] == "PrometheusRule"]
    path = directory / "rules.yaml"
    path.write_text(yaml.safe_dump(rule["spec"], sort_keys=False))
    return path


def alert_names(rules_file: pathlib.Path) -> set[str]:
    groups = yaml.safe_load(rules_file.read_text())["groups"]
    return {r["alert"] for g in groups for r in g["rules"] if "alert" in r}
