"""The chart's rules pass `promtool check rules`, and `promtool test rules` (rules_test.yaml) fires each alert where it
should and nowhere else, at the chart's default values."""

from __future__ import annotations

import pathlib
import shutil
import subprocess

import yaml

from tests.monitoring.monitoring_helpers import alert_names, program, render_rules

HERE = pathlib.Path(__file__).parent
UNIT_TESTS = HERE / "rules_test.yaml"


def test_promtool_checks_the_rules(helm, tmp_path):
    promtool = program("promtool")
    rules = render_rules(helm, tmp_path)
    result = subprocess.run([promtool, "check", "rules", rules], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "SUCCESS" in result.stdout


def test_promtool_unit_tests_cover_every_alert_and_pass(helm, tmp_path):
    promtool = program("promtool")
    rules = render_rules(helm, tmp_path)
    tests = yaml.safe_load(UNIT_TESTS.read_text())["tests"]
    cases = [c for t in tests for c in t.get("alert_rule_test", [])]
    for name in alert_names(rules):  # each alert: a case where it fires, and one where it does not
        assert any(c["alertname"] == name and c["exp_alerts"] for c in cases), f"{name} never fires in {UNIT_TESTS}"
        assert any(c["alertname"] == name and not c["exp_alerts"] for c in cases), f"{name} always fires"
    shutil.copy(UNIT_TESTS, tmp_path / UNIT_TESTS.name)
    result = subprocess.run(
        [promtool, "test", "rules", tmp_path / UNIT_TESTS.name], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stdout + result.stderr
