"""The pure parts of tracing: the W3C trace context as received (hostile), the OTel variables, the netapp's spans
from a frame's stamps, and the offset that lines the robot's spans up with the netapp's."""

from __future__ import annotations

import pytest

from netapp import tracecontext
from netapp.client.timing import span_offset
from netapp.server.pipeline.frame import FrameTrace
from netapp.server.pipeline.tracing import FrameStamps, frame_spans
from netapp.tracing import TraceConfig

VALID = "00-4bf92f3577b34da6a3ce929d0e0e4736-00f067aa0ba902b7-01"


def test_a_valid_traceparent_round_trips_with_its_tracestate():
    context = tracecontext.parse(VALID, "rojo=00f067aa0ba902b7, congo=t61rcWkgMzE")
    assert context is not None and context.sampled
    assert context.traceparent() == VALID
    assert context.fields() == {"traceparent": VALID, "tracestate": "rojo=00f067aa0ba902b7,congo=t61rcWkgMzE"}
    assert tracecontext.parse(VALID[:-2] + "00").sampled is False


@pytest.mark.parametrize(
    "value",
    [
        None,
        42,
        "",
        VALID[:-1],  # short
        VALID + "-",  # version 00 is exactly 55 characters
        VALID.upper(),  # lowercase hex only
        "ff" + VALID[2:],  # the forbidden version
        "00-" + "0" * 32 + VALID[35:],  # an all-zero trace id
        VALID[:36] + "0" * 16 + VALID[52:],  # an all-zero span id
        VALID.replace("-", "_"),
        "0" * 10_000,
    ],
)
def test_a_malformed_traceparent_is_ignored(value):
    assert tracecontext.parse(value) is None
    assert tracecontext.from_mapping({"traceparent": value}) is None


def test_a_future_version_is_read_by_its_first_55_characters():
    context = tracecontext.parse("cc" + VALID[2:] + "-what-comes-next")
    assert context is not None and context.span_id == 0x00F067AA0BA902B7


@pytest.mark.parametrize("state", ["x" * 513, "Bad Key=1", "a=1," * 33, "a=b=,c"])
def test_a_bad_tracestate_is_dropped_and_the_traceparent_kept(state):
    context = tracecontext.parse(VALID, state)
    assert context is not None and context.tracestate == ""


def test_tracing_is_off_unless_an_endpoint_is_configured():
    assert TraceConfig.from_env("netapp", {}) is None
    assert TraceConfig.from_env("netapp", {"OTEL_TRACES_SAMPLER": "always_on"}) is None
    on = {"OTEL_EXPORTER_OTLP_ENDPOINT": "http://collector:4318/"}
    assert TraceConfig.from_env("netapp", {**on, "OTEL_SDK_DISABLED": "true"}) is None
    assert TraceConfig.from_env("netapp", {**on, "OTEL_TRACES_EXPORTER": "none"}) is None
    config = TraceConfig.from_env("netapp", on)
    assert config == TraceConfig("http://collector:4318/v1/traces", "netapp", "parentbased_always_on", 1.0, 5000.0)
    config = TraceConfig.from_env(
        "netapp",
        {
            "OTEL_EXPORTER_OTLP_TRACES_ENDPOINT": "http://c:4318/custom",
            "OTEL_TRACES_SAMPLER": "parentbased_traceidratio",
            "OTEL_TRACES_SAMPLER_ARG": "0.01",
            "OTEL_SERVICE_NAME": "edge-netapp",
        },
    )
    assert (config.endpoint, config.sampler, config.ratio, config.service_name) == (
        "http://c:4318/custom",
        "parentbased_traceidratio",
        0.01,
        "edge-netapp",
    )


@pytest.mark.parametrize(
    "env, says",
    [
        ({"OTEL_TRACES_SAMPLER": "jaeger_remote"}, "OTEL_TRACES_SAMPLER=jaeger_remote: use one of"),
        ({"OTEL_TRACES_SAMPLER": "traceidratio", "OTEL_TRACES_SAMPLER_ARG": "2"}, "in [0, 1]"),
        ({"OTEL_TRACES_SAMPLER": "traceidratio", "OTEL_TRACES_SAMPLER_ARG": "x"}, "in [0, 1]"),
        ({"OTEL_EXPORTER_OTLP_PROTOCOL": "grpc"}, "set http/protobuf"),
    ],
)
def test_a_wrong_variable_is_one_line_saying_which(env, says):
    with pytest.raises(ValueError, match=None) as raised:
        TraceConfig.from_env("netapp", {"OTEL_EXPORTER_OTLP_ENDPOINT": "http://c:4318", **env})
    assert says in str(raised.value) and "\n" not in str(raised.value)


def test_the_netapps_spans_follow_its_stamps():
    trace = FrameTrace(trace_id=7, span_id=70, parent_id=9)
    # decoded on the inference thread at its turn: queued from receipt
    spans = frame_spans(trace, FrameStamps(100, (210, 230), 200, 240, 300, 310), 1_000, {"a": 1})
    got = {s.name: (s.parent_id, s.start_ns - 1_000, s.end_ns - 1_000) for s in spans}
    assert got == {
        "netapp.frame": (9, 100, 310),
        "queue": (70, 100, 200),
        "decode": (70, 210, 230),
        "inference": (70, 240, 300),
        "deliver": (70, 300, 310),
    }
    assert spans[0].remote_parent and spans[0].kind == "server" and spans[0].attributes == {"a": 1}
    # decoded ahead on the prepare pool: queued from the end of decoding
    spans = frame_spans(FrameTrace(7, 70), FrameStamps(100, (110, 150), 200, 205, 300, 310), 0, {})
    assert {s.name: (s.start_ns, s.end_ns) for s in spans}["queue"] == (150, 200)
    assert spans[0].parent_id == 0 and not spans[0].remote_parent  # no robot's context: a root


def test_the_span_offset_keeps_the_robots_spans_around_the_netapps():
    t1, t2, t3, t4 = 1_000, 5_000, 9_000, 10_000  # a netapp clock 3_000 ahead; 1_000 up, 1_000 down, +1_000 encode
    assert span_offset(3_000, t1, t2, t3, t4) == 3_000
    assert span_offset(4_500, t1, t2, t3, t4) == 4_000  # too far ahead: the frame would leave after its receipt
    assert span_offset(-5_000, t1, t2, t3, t4) == -1_000  # too far behind: its result would arrive before it left
