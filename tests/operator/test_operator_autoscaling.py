"""Autoscaling on the netapps' own signals: HPAs validated against the Kubernetes schemas, ScaledObjects against
the KEDA schema subset in tests/support/schemas (written from KEDA's documented fields; see that file)."""

from __future__ import annotations

import pathlib

import jsonschema
import pytest
import yaml
from netapp_operator.autoscaling import METRICS, Autoscaling, problems, quantity, render_autoscaler

from netapp.protocol import METRIC_LATENCY, METRIC_ROBOTS
from tests.support.kubernetes_versions import KUBERNETES_VERSIONS

KEDA_SCHEMA = yaml.safe_load(
    (pathlib.Path(__file__).parents[1] / "support" / "schemas" / "keda-scaledobject-v1alpha1.yaml").read_text()
)
META = {"name": "det-edge", "namespace": "ns", "labels": {"app.kubernetes.io/name": "netapp"}}
PROMETHEUS = "http://prometheus.monitoring.svc:9090"


@pytest.mark.parametrize("metric", METRICS)
def test_every_hpa_is_valid_kubernetes(metric):
    kubernetes_validate = pytest.importorskip("kubernetes_validate")
    hpa = render_autoscaler(META, "det-edge", Autoscaling(1, 5, metric=metric))
    for version in KUBERNETES_VERSIONS:
        kubernetes_validate.validate(hpa, version, strict=True)


@pytest.mark.parametrize("metric", METRICS)
def test_every_scaled_object_is_valid_keda(metric):
    scaled = render_autoscaler(
        META, "det-edge", Autoscaling(1, 5, metric=metric, engine="keda", prometheus_address=PROMETHEUS)
    )
    jsonschema.validate(scaled, KEDA_SCHEMA)


def test_the_keda_schema_refuses_what_keda_would_not_take():
    scaled = render_autoscaler(
        META, "d", Autoscaling(1, 5, metric="latency", engine="keda", prometheus_address=PROMETHEUS)
    )
    for broken in (
        {**scaled, "spec": {**scaled["spec"], "triggers": []}},
        {**scaled, "spec": {**scaled["spec"], "maxReplicas": 3}},  # HPA's spelling, not KEDA's
        {**scaled, "spec": {**scaled["spec"], "triggers": [{"type": "prometheus", "metadata": {"query": "x"}}]}},
    ):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(broken, KEDA_SCHEMA)


def test_an_hpa_on_robots_per_replica_is_a_pods_metric():
    hpa = render_autoscaler(META, "det-edge", Autoscaling(2, 6, metric="robotsPerReplica", target=3))
    assert hpa["spec"]["minReplicas"] == 2 and hpa["spec"]["maxReplicas"] == 6
    assert hpa["spec"]["scaleTargetRef"] == {"apiVersion": "apps/v1", "kind": "Deployment", "name": "det-edge"}
    assert hpa["spec"]["metrics"] == [
        {
            "type": "Pods",
            "pods": {"metric": {"name": METRIC_ROBOTS}, "target": {"type": "AverageValue", "averageValue": "3"}},
        }
    ]


def test_cpu_stays_a_resource_metric():
    (metric,) = render_autoscaler(META, "d", Autoscaling(1, 3, target_cpu_percent=60))["spec"]["metrics"]
    target = {"type": "Utilization", "averageUtilization": 60}
    assert metric == {"type": "Resource", "resource": {"name": "cpu", "target": target}}


def test_a_latency_target_is_a_milli_quantity_and_keda_averages_it():
    (metric,) = render_autoscaler(META, "d", Autoscaling(1, 3, metric="latency", target=0.25))["spec"]["metrics"]
    assert metric["pods"]["target"]["averageValue"] == "250m"
    scaled = render_autoscaler(
        META, "det-edge", Autoscaling(1, 3, metric="latency", target=0.25, engine="keda", prometheus_address=PROMETHEUS)
    )
    (trigger,) = scaled["spec"]["triggers"]
    assert trigger["type"] == "prometheus" and trigger["metricType"] == "Value"
    assert trigger["metadata"]["threshold"] == "0.25"
    pods = 'pod=~"det-edge-[a-z0-9]+-[a-z0-9]+"'
    assert trigger["metadata"]["query"] == f'avg({METRIC_LATENCY}{{namespace="ns",{pods}}})'
    assert scaled["spec"]["minReplicaCount"] == 1 and scaled["spec"]["maxReplicaCount"] == 3


def test_keda_sums_an_additive_signal_against_a_per_replica_threshold():
    scaled = render_autoscaler(
        META, "d", Autoscaling(1, 3, metric="robotsPerReplica", engine="keda", prometheus_address=PROMETHEUS)
    )
    (trigger,) = scaled["spec"]["triggers"]
    assert trigger["metricType"] == "AverageValue" and trigger["metadata"]["threshold"] == "4"
    assert trigger["metadata"]["query"].startswith(f"sum({METRIC_ROBOTS}{{")


def test_problems_say_what_to_fix():
    assert problems(Autoscaling(1, 3)) == []
    assert "prometheusAddress is required" in problems(Autoscaling(1, 3, metric="latency", engine="keda"))[0]
    assert "metric must be one of" in problems(Autoscaling(1, 3, metric="gpu"))[0]
    assert "engine must be one of" in problems(Autoscaling(1, 3, engine="knative"))[0]
    assert "target must be a number > 0" in problems(Autoscaling(1, 3, metric="latency", target=0))[0]


def test_quantities():
    assert [quantity(v) for v in (4, 4.0, 0.25, 1.5)] == ["4", "4", "250m", "1500m"]
