"""A deployment's trace (docs/tracing.md): the robot's `deploy` span, the middleware's `middleware.deploy` under
it, and `netapp.create`, `netapp.ready`, `url.handed_out` under that, one trace, in time order, exported to a real
OTLP receiver; a NetApp created on Kubernetes carries the deploy span's traceparent for its reconcile to join."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("opentelemetry.sdk", reason="the tracing extra is absent: pip install 'netapp-toolkit[tracing]'")
pytest.importorskip("opentelemetry.proto", reason="the tracing extra is absent: pip install 'netapp-toolkit[tracing]'")

from netapp_middleware.backends.kubernetes import KubernetesBackend  # noqa: E402
from netapp_middleware.backends.local import LocalBackend  # noqa: E402
from netapp_operator.constants import ANNOTATION_TRACEPARENT  # noqa: E402

from netapp import tracecontext  # noqa: E402
from netapp.client.middleware import MiddlewareClient  # noqa: E402
from netapp.client.tracing import RootSpan  # noqa: E402
from netapp.tracing import TraceConfig, Tracer  # noqa: E402
from tests.middleware.mw_helpers import DEADLINE_S, NS, ROBOTS, Operator  # noqa: E402
from tests.support.otlp import OtlpReceiver, ReceivedSpan  # noqa: E402

MIDDLEWARE = {"middleware.deploy", "netapp.create", "netapp.ready", "url.handed_out"}


@pytest.fixture
def otlp() -> Iterator[OtlpReceiver]:
    with OtlpReceiver() as receiver:
        yield receiver


@pytest.fixture
def tracers(otlp: OtlpReceiver) -> Iterator[tuple[Tracer, Tracer]]:
    """(the middleware's, the robot's)"""
    made = [
        Tracer(TraceConfig(f"{otlp.endpoint}/v1/traces", service, sampler, schedule_delay_ms=50))
        for service, sampler in (("netapp-middleware", "parentbased_always_on"), ("robot", "always_on"))
    ]
    yield made[0], made[1]
    for tracer in made:
        tracer.shutdown()


def named(spans: list[ReceivedSpan], trace_id: str) -> dict[str, ReceivedSpan]:
    return {s.name: s for s in spans if s.trace_id == trace_id}


def test_a_deployment_is_one_trace_from_the_robots_request_to_its_url(
    start_middleware: Any, tiny_model_path: Path, otlp: OtlpReceiver, tracers: tuple[Tracer, Tracer]
) -> None:
    middleware_tracer, robot_tracer = tracers
    backend = LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S)
    server = start_middleware(backend, tracer=middleware_tracer)
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"], tracer=robot_tracer) as mw:
        endpoint = mw.deploy("object-detection", placement="edge", timeout=2 * DEADLINE_S)
        with MiddlewareClient(server.url, "robot-2", ROBOTS["robot-2"], tracer=robot_tracer) as other:
            assert other.deploy("object-detection", placement="edge", timeout=DEADLINE_S).url == endpoint.url
    robot_tracer.flush()
    middleware_tracer.flush()
    spans = otlp.wait_for(lambda spans: len(spans) >= 2 + len(MIDDLEWARE) + 2)
    first, second = sorted((s for s in spans if s.name == "deploy"), key=lambda s: s.start_ns)
    trace = named(spans, first.trace_id)
    assert set(trace) == {"deploy", *MIDDLEWARE}
    deploy = trace["middleware.deploy"]
    assert first.service == "robot" and first.parent_id == "" and first.kind == "client"
    assert deploy.service == "netapp-middleware" and deploy.kind == "server" and deploy.parent_id == first.span_id
    assert all(trace[n].parent_id == deploy.span_id for n in MIDDLEWARE - {"middleware.deploy"})
    create, ready, handed = trace["netapp.create"], trace["netapp.ready"], trace["url.handed_out"]
    assert first.start_ns <= deploy.start_ns <= create.start_ns <= create.end_ns <= ready.start_ns
    assert ready.end_ns <= handed.end_ns == deploy.end_ns <= first.end_ns
    assert deploy.attributes["netapp.url"] == endpoint.url and deploy.attributes["netapp.placement"] == "edge"
    # The second robot reused the running NetApp: nothing was created or waited for.
    assert set(named(spans, second.trace_id)) == {"deploy", "middleware.deploy", "url.handed_out"}


def test_a_netapp_on_kubernetes_carries_the_deployments_traceparent(
    kube_api: Any, start_middleware: Any, otlp: OtlpReceiver, tracers: tuple[Tracer, Tracer]
) -> None:
    middleware_tracer, robot_tracer = tracers
    server = start_middleware(KubernetesBackend(NS, kube_api.new_kube()), tracer=middleware_tracer)
    operator = Operator(kube_api)
    span = RootSpan(robot_tracer, "deploy", {})
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"], tracer=robot_tracer) as mw:
        view = mw.create("object-detection", placement="edge", trace=span.context.fields())
        netapp = operator.the_one()
        annotated = tracecontext.parse(netapp["metadata"]["annotations"][ANNOTATION_TRACEPARENT])
        assert annotated is not None and annotated.trace_id == span.context.trace_id and annotated.sampled
        operator.set_status(netapp["metadata"]["name"], "Ready", url="http://10.0.0.7:5896", pool="edge")
        assert mw.status(view["id"], wait=DEADLINE_S, since=view["version"])["status"] == "Ready"
    middleware_tracer.flush()
    trace = named(otlp.wait_for(lambda spans: len(spans) >= len(MIDDLEWARE)), f"{span.context.trace_id:032x}")
    assert set(trace) == MIDDLEWARE
    # Whatever reconciles the NetApp joins the trace under the middleware's deploy span.
    assert f"{annotated.span_id:016x}" == trace["middleware.deploy"].span_id
