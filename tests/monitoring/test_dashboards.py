"""The dashboards in the chart are what tools/dashboards.py makes (byte for byte), and each panel asks something.
That every panel's query returns series from a real Prometheus: test_live.py and test_control_plane.py."""

from __future__ import annotations

import json

import pytest

from tools import dashboards


def test_the_committed_dashboards_are_what_the_code_makes():
    pytest.importorskip("grafana_foundation_sdk", reason="pip install grafana-foundation-sdk (Python 3.11 or later)")
    files = sorted(p.name for p in dashboards.OUT.glob("*.json"))
    assert files == sorted(f"{d.uid}.json" for d in dashboards.DASHBOARDS)
    for spec in dashboards.DASHBOARDS:
        assert (dashboards.OUT / f"{spec.uid}.json").read_text() == dashboards.render(spec), (
            f"{spec.uid}.json is stale: python -m tools.dashboards"
        )


def test_every_panel_queries_prometheus_through_the_datasource_variable():
    for path in dashboards.OUT.glob("*.json"):
        board = json.loads(path.read_text())
        assert board["panels"], path.name
        for panel in board["panels"]:
            assert panel["datasource"] == {"type": "prometheus", "uid": "${datasource}"}
            assert panel["targets"] and all(t["expr"] and t["legendFormat"] for t in panel["targets"]), panel["title"]
