"""What the monitoring tests share: the chart's rules rendered by helm (the one copy, files/rules.yaml), and Debian's
Prometheus programs, each skipped with the install hint where absent."""

from __future__ import annotations

import json
import pathlib
import shutil
from typing import Any

import pytest
import yaml

from tests.chart.chart_helpers import CHART, template

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


def short_rules(**values: Any) -> dict[str, Any]:
    """monitoring.rules for a test that must see alerts within seconds: 10 s windows (5 scrapes: a late scrape leaves
    enough for a rate) and every alert's `for` 2 s (the alerts named as the chart's values.yaml names them), and
    `values` besides."""
    defaults = yaml.safe_load((CHART / "values.yaml").read_text())["monitoring"]["rules"]
    return {"window": "10s", "for": dict.fromkeys(defaults["for"], "2s"), **values}


def alert_names(rules_file: pathlib.Path) -> set[str]:
    groups = yaml.safe_load(rules_file.read_text())["groups"]
    return {r["alert"] for g in groups for r in g["rules"] if "alert" in r}


DASHBOARDS = CHART / "files" / "dashboards"
# What Grafana would put in the queries: every value of each variable, and a rate window the test's data fills.
VARIABLES = {"$__rate_interval": "1m", "$namespace": ".+", "$netapp": ".+", "$robot": ".+"}


def dashboard_queries() -> list[tuple[str, str, str]]:
    """(dashboard, panel, query) for every target of every panel of the chart's dashboards, the variables filled."""
    found = []
    for path in sorted(DASHBOARDS.glob("*.json")):
        board = json.loads(path.read_text())
        for panel in board["panels"]:
            for target in panel["targets"]:
                expr = target["expr"]
                for name, value in VARIABLES.items():
                    expr = expr.replace(name, value)
                assert "$" not in expr, f"{board['title']} / {panel['title']}: a variable no test fills: {expr}"
                found.append((board["title"], panel["title"], expr))
    return found
