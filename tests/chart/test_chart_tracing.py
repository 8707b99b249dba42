"""The chart's `tracing.env` (docs/tracing.md): off by default (no env at all), passed to the middleware and the
operator when set, and only OTEL_* variables taken."""

from __future__ import annotations

from tests.chart.chart_helpers import CHART, run, template


def containers(objects: list[dict]) -> dict[str, dict]:
    deployments = [o for o in objects if o["kind"] == "Deployment"]
    return {c["name"]: c for d in deployments for c in d["spec"]["template"]["spec"]["containers"]}


def test_tracing_is_off_by_default_and_passed_to_the_control_plane_when_set(helm, tmp_path):
    off = containers(template(helm)).values()
    assert not [e for c in off for e in c.get("env", []) if e["name"].startswith("OTEL_")]
    values = tmp_path / "tracing.yaml"
    values.write_text(
        "tracing:\n  env:\n    OTEL_EXPORTER_OTLP_ENDPOINT: http://otel-collector.monitoring:4318\n"
        "    OTEL_TRACES_SAMPLER: parentbased_traceidratio\n    OTEL_TRACES_SAMPLER_ARG: '0.01'\n"
    )
    found = containers(template(helm, values))
    for name in ("middleware", "operator"):
        env = {e["name"]: e["value"] for e in found[name]["env"] if "value" in e}  # (not the operator's Secret)
        assert env == {
            "OTEL_EXPORTER_OTLP_ENDPOINT": "http://otel-collector.monitoring:4318",
            "OTEL_TRACES_SAMPLER": "parentbased_traceidratio",
            "OTEL_TRACES_SAMPLER_ARG": "0.01",
        }


def test_only_otel_variables_are_taken(helm, tmp_path):
    values = tmp_path / "values.yaml"
    values.write_text("tracing: {env: {NETAPP_TOKEN: leaked}}\n")
    result = run(helm, "template", "x", CHART, "--values", values, check=False)
    assert result.returncode != 0 and "'NETAPP_TOKEN' does not match pattern '^OTEL_" in result.stderr, result.stderr
