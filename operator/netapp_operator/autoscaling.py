"""Autoscaling a NetApp's Deployment (pure): on CPU, or on what its netapps measure and publish in /metrics
(robots per replica, load over the measured capacity, queue depth, result latency), rendered as an
autoscaling/v2 HorizontalPodAutoscaler on a Pods metric (served by the Prometheus adapter's custom metrics API) or
as a KEDA ScaledObject with a Prometheus trigger.

A signal is either additive over replicas (robots, queued frames: the desired count is the total over the target
per replica) or an average (load, latency: the desired count grows with the ratio of the average to the target).
An HPA's Pods metric is averaged over the pods either way, which fits both; KEDA's Prometheus trigger reads one
number, so an additive signal is queried as a sum with `AverageValue` and an average as an average with `Value`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from netapp.protocol import METRIC_LATENCY, METRIC_LOAD, METRIC_QUEUE, METRIC_ROBOTS
from netapp_operator.spec import AUTOSCALING_METRICS, Autoscaling

KEDA_API_VERSION = "keda.sh/v1alpha1"
SCALED_OBJECT_KIND = "ScaledObject"


@dataclass(frozen=True)
class Signal:
    metric: str  # the netapp's gauge
    additive: bool  # summed over replicas (else averaged)
    default_target: float  # per replica (additive) or the average to hold
    unit: str  # for messages and docs/scaling.md


SIGNALS: dict[str, Signal] = {  # keyed by spec.AUTOSCALING_METRICS beyond cpu
    "robotsPerReplica": Signal(METRIC_ROBOTS, True, 4, "robots per replica"),
    "capacityLoad": Signal(METRIC_LOAD, False, 0.9, "robots over the measured optimal limit"),
    "queueDepth": Signal(METRIC_QUEUE, True, 2, "frames waiting per replica"),
    "latency": Signal(METRIC_LATENCY, False, 0.2, "seconds from receive to result"),
}
assert ("cpu", *SIGNALS) == AUTOSCALING_METRICS


def target_value(auto: Autoscaling) -> float:
    """The signal's target: the spec's, else the signal's default."""
    return auto.target if auto.target is not None else SIGNALS[auto.metric].default_target


def quantity(value: float) -> str:
    """A Kubernetes quantity for a target: whole numbers as they are, fractions in milli-units ("250m")."""
    if float(value).is_integer():
        return str(int(value))
    return f"{round(value * 1000)}m"


def _number(value: float) -> str:
    """KEDA's thresholds are plain decimal strings."""
    return str(int(value)) if float(value).is_integer() else repr(float(value))


def render_hpa(meta: dict[str, Any], deployment: str, auto: Autoscaling) -> dict[str, Any]:
    """An autoscaling/v2 HPA on CPU, or on the netapp's gauge as a Pods metric averaged over the pods."""
    if auto.metric == "cpu":
        metric: dict[str, Any] = {
            "type": "Resource",
            "resource": {
                "name": "cpu",
                "target": {"type": "Utilization", "averageUtilization": int(auto.target_cpu_percent)},
            },
        }
    else:
        metric = {
            "type": "Pods",
            "pods": {
                "metric": {"name": SIGNALS[auto.metric].metric},
                "target": {"type": "AverageValue", "averageValue": quantity(target_value(auto))},
            },
        }
    return {
        "apiVersion": "autoscaling/v2",
        "kind": "HorizontalPodAutoscaler",
        "metadata": meta,
        "spec": {
            "scaleTargetRef": {"apiVersion": "apps/v1", "kind": "Deployment", "name": deployment},
            "minReplicas": int(auto.min_replicas),
            "maxReplicas": int(auto.max_replicas),
            "metrics": [metric],
        },
    }


def prometheus_query(signal: Signal, namespace: str, deployment: str) -> str:
    """The PromQL KEDA runs: the gauge of this Deployment's pods, summed or averaged."""
    selector = f'{{namespace="{namespace}",pod=~"{deployment}-[a-z0-9]+-[a-z0-9]+"}}'
    return f"{'sum' if signal.additive else 'avg'}({signal.metric}{selector})"


def render_scaled_object(meta: dict[str, Any], deployment: str, auto: Autoscaling) -> dict[str, Any]:
    """A KEDA ScaledObject: a Prometheus trigger on the netapp's gauge, or KEDA's cpu trigger."""
    if auto.metric == "cpu":
        trigger: dict[str, Any] = {
            "type": "cpu",
            "metricType": "Utilization",
            "metadata": {"value": str(auto.target_cpu_percent)},
        }
    else:
        signal = SIGNALS[auto.metric]
        trigger = {
            "type": "prometheus",
            "metricType": "AverageValue" if signal.additive else "Value",
            "metadata": {
                "serverAddress": auto.prometheus_address,
                "query": prometheus_query(signal, meta["namespace"], deployment),
                "threshold": _number(target_value(auto)),
            },
        }
    return {
        "apiVersion": KEDA_API_VERSION,
        "kind": SCALED_OBJECT_KIND,
        "metadata": meta,
        "spec": {
            "scaleTargetRef": {"apiVersion": "apps/v1", "kind": "Deployment", "name": deployment},
            "minReplicaCount": int(auto.min_replicas),
            "maxReplicaCount": int(auto.max_replicas),
            "triggers": [trigger],
        },
    }


def render_autoscaler(meta: dict[str, Any], deployment: str, auto: Autoscaling) -> dict[str, Any]:
    """The HPA or the ScaledObject, whichever `engine` asks."""
    return (render_scaled_object if auto.engine == "keda" else render_hpa)(meta, deployment, auto)
