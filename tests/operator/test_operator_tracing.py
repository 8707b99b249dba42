"""The operator joins a deployment's trace (docs/tracing.md): a NetApp annotated with the deploy span's
traceparent gets an `operator.reconcile` span under it for each reconcile that changed something; a NetApp without
one gets none. The real handlers against the API emulator, exporting to a real OTLP receiver."""

from __future__ import annotations

from typing import Any

import pytest

pytest.importorskip("opentelemetry.sdk", reason="the tracing extra is absent: pip install 'netapp-toolkit[tracing]'")
pytest.importorskip("opentelemetry.proto", reason="the tracing extra is absent: pip install 'netapp-toolkit[tracing]'")

from netapp_operator import handlers  # noqa: E402
from netapp_operator.constants import ANNOTATION_TRACEPARENT  # noqa: E402

from netapp import tracecontext  # noqa: E402
from netapp.tracing import TraceConfig, Tracer  # noqa: E402
from tests.operator.op_harness import running_operator  # noqa: E402
from tests.operator.op_helpers import eventually, netapp, setup_pools  # noqa: E402
from tests.support.otlp import OtlpReceiver  # noqa: E402

pytestmark = pytest.mark.timeout(120)


async def test_a_traced_netapps_reconciles_join_its_deployments_trace(
    api: Any, emulator: Any, operator_config: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    with OtlpReceiver() as otlp:
        tracer = Tracer(TraceConfig(f"{otlp.endpoint}/v1/traces", "netapp-operator", schedule_delay_ms=50))
        monkeypatch.setattr(handlers, "tracer_from_env", lambda service: tracer)
        deploy = tracecontext.TraceContext(tracecontext.new_trace_id(), tracecontext.new_span_id(), True)
        async with running_operator(emulator, operator_config):
            await setup_pools(api)
            traced = netapp("traced")
            traced["metadata"]["annotations"] = {ANNOTATION_TRACEPARENT: deploy.traceparent()}
            await api.apply(traced)
            await api.apply(netapp("untraced"))

            async def placed() -> bool:
                statuses = [(await api.get("NetApp", "default", n)).get("status") or {} for n in ("traced", "untraced")]
                return all(s.get("url") for s in statuses)

            await eventually(placed, what="both NetApps placed")
        assert tracer.flush()
        tracer.shutdown()
        spans = otlp.spans
    assert spans, "no reconcile span"
    assert {s.name for s in spans} == {"operator.reconcile"} and {s.service for s in spans} == {"netapp-operator"}
    assert {(s.trace_id, s.parent_id) for s in spans} == {(f"{deploy.trace_id:032x}", f"{deploy.span_id:016x}")}
    assert {s.attributes["netapp.name"] for s in spans} == {"traced"}  # the untraced one made none
    assert any(s.attributes.get("netapp.action") == "place" for s in spans)
