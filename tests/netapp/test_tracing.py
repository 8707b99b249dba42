"""Frame traces end to end (docs/tracing.md): a real netapp and a real NetAppClient export to a real OTLP/HTTP
receiver on loopback; one trace per sampled frame with every span, parents right, robot and netapp spans in time
order, on every transport; nothing when the robot samples nothing; 5G-ERA robots without trace context served as
before (the netapp samples them by its own sampler)."""

from __future__ import annotations

import os
import subprocess
import sys
from collections import defaultdict

import cv2
import numpy as np
import pytest
import requests

pytest.importorskip("opentelemetry.sdk", reason="the tracing extra is absent: pip install 'netapp-toolkit[tracing]'")
pytest.importorskip("opentelemetry.proto", reason="the tracing extra is absent: pip install 'netapp-toolkit[tracing]'")

from netapp.client import NetAppClient  # noqa: E402
from netapp.server.app import create_app  # noqa: E402
from netapp.server.runner import uvicorn_options  # noqa: E402
from netapp.server.settings import Settings  # noqa: E402
from netapp.tracing import TraceConfig, Tracer  # noqa: E402
from tests.support.images import make_jpeg  # noqa: E402
from tests.support.otlp import OtlpReceiver, ReceivedSpan  # noqa: E402
from tests.support.paths import ROOT  # noqa: E402
from tests.support.raw_robot import RawRobot  # noqa: E402
from tests.support.servers import BackgroundServer  # noqa: E402

ROBOT = {"frame", "send", "receive"}
NETAPP = {"netapp.frame", "decode", "queue", "inference", "deliver"}
FRAMES = 3


@pytest.fixture
def otlp():
    with OtlpReceiver() as receiver:
        yield receiver


def tracer(otlp: OtlpReceiver, service: str, sampler: str = "parentbased_always_on", ratio: float = 1.0) -> Tracer:
    return Tracer(TraceConfig(f"{otlp.endpoint}/v1/traces", service, sampler, ratio, schedule_delay_ms=50))


@pytest.fixture
def traced_netapp(otlp, tiny_detector):
    """A netapp tracing as its own sampler says (parent-based: the robot decides), decoding on its inference thread,
    and its tracer."""
    netapp_tracer = tracer(otlp, "netapp")
    settings = Settings(lanes=1, prepare_threads=0)
    with BackgroundServer(create_app(tiny_detector, settings, netapp_tracer), **uvicorn_options(settings)) as server:
        yield server, netapp_tracer
    netapp_tracer.shutdown()


def by_trace(spans: list[ReceivedSpan]) -> dict[str, dict[str, ReceivedSpan]]:
    traces: dict[str, dict[str, ReceivedSpan]] = defaultdict(dict)
    for span in spans:
        assert span.name not in traces[span.trace_id], f"two {span.name} spans in one trace"
        traces[span.trace_id][span.name] = span
    return traces


def stream(url: str, transport: str, robot_tracer: Tracer, frames: int = FRAMES, codec: str | None = None) -> list:
    """Send `frames` frames one after the other, each after the previous result; their results."""
    results = []
    with NetAppClient(url, transport=transport, codec=codec, tracer=robot_tracer, max_in_flight=1) as client:
        image = cv2.imdecode(np.frombuffer(make_jpeg(), np.uint8), cv2.IMREAD_COLOR)
        for _ in range(frames):
            client.send(image)
            results.append(next(client.results(timeout=10)))
    return results


@pytest.mark.parametrize(
    "transport, codec", [("http", None), ("ws", None), ("frames", None), ("frames", "h264")], ids=lambda v: v or ""
)
def test_one_trace_per_sampled_frame_with_every_span_parents_right_in_time_order(otlp, traced_netapp, transport, codec):
    if codec == "h264":
        pytest.importorskip("av", reason="PyAV is absent: pip install 'netapp-toolkit[h264]'")
    server, netapp_tracer = traced_netapp
    robot_tracer = tracer(otlp, "robot", "always_on")
    results = stream(server.url, transport, robot_tracer, codec=codec)
    assert [r.detections[0]["class_name"] for r in results] == ["robot"] * FRAMES  # served as ever
    robot_tracer.flush()
    netapp_tracer.flush()
    spans = otlp.wait_for(lambda spans: len(spans) >= FRAMES * 8)
    traces = by_trace(spans)
    assert len(traces) == FRAMES, "one trace per frame"
    for trace in traces.values():
        assert set(trace) == ROBOT | NETAPP
        root, frame = trace["frame"], trace["netapp.frame"]
        assert {trace[n].service for n in ROBOT} == {"robot"} and {trace[n].service for n in NETAPP} == {"netapp"}
        assert root.parent_id == "" and root.kind == "client"
        assert frame.kind == "server" and frame.parent_id == root.span_id  # the robot's traceparent, followed
        assert trace["send"].parent_id == trace["receive"].parent_id == root.span_id
        assert all(trace[n].parent_id == frame.span_id for n in NETAPP - {"netapp.frame"})
        assert frame.attributes["netapp.transport"] == ("frames-h264" if codec else transport)
        # Robot and netapp spans line up: the robot's clock offset puts its spans around the netapp's.
        assert root.start_ns <= frame.start_ns <= frame.end_ns <= trace["receive"].start_ns <= root.end_ns
        for name in NETAPP - {"netapp.frame"}:
            assert frame.start_ns <= trace[name].start_ns <= trace[name].end_ns <= frame.end_ns, name
        # Decoding on the inference thread: queued, decoded at its turn, inferred, delivered.
        queue, decode, inference, deliver = (trace[n] for n in ("queue", "decode", "inference", "deliver"))
        assert queue.end_ns <= decode.start_ns <= decode.end_ns <= inference.start_ns
        assert inference.end_ns <= deliver.start_ns and deliver.end_ns == frame.end_ns
    robot_tracer.shutdown()


def test_a_frame_decoded_ahead_waits_in_the_queue_after_its_decode(otlp, tiny_detector):
    netapp_tracer = tracer(otlp, "netapp")
    settings = Settings(lanes=1, prepare_threads=1)  # JPEGs decoded on the prepare pool, before their turn
    with BackgroundServer(create_app(tiny_detector, settings, netapp_tracer), **uvicorn_options(settings)) as server:
        robot_tracer = tracer(otlp, "robot", "always_on")
        stream(server.url, "http", robot_tracer, frames=1)
    robot_tracer.flush()
    netapp_tracer.flush()
    (trace,) = by_trace(otlp.wait_for(lambda spans: len(spans) >= 8)).values()
    assert trace["decode"].end_ns <= trace["queue"].start_ns <= trace["queue"].end_ns <= trace["inference"].start_ns
    robot_tracer.shutdown()
    netapp_tracer.shutdown()


def test_a_robot_that_samples_nothing_gets_no_spans_from_anyone(otlp, traced_netapp):
    """The sampling decision is the robot's: the netapp's parent-based sampler follows an unsampled traceparent."""
    server, netapp_tracer = traced_netapp
    robot_tracer = tracer(otlp, "robot", "always_off")
    results = stream(server.url, "frames", robot_tracer)
    assert len(results) == FRAMES
    assert robot_tracer.flush() and netapp_tracer.flush()  # everything queued is exported before these return
    assert otlp.spans == [] and otlp.requests == 0
    robot_tracer.shutdown()


def test_a_one_percent_robot_traces_only_the_frames_its_sampler_picks(otlp, traced_netapp):
    server, netapp_tracer = traced_netapp
    robot_tracer = tracer(otlp, "robot", "traceidratio", 0.01)
    stream(server.url, "ws", robot_tracer, frames=20)
    robot_tracer.flush()
    netapp_tracer.flush()  # the netapp makes a frame's spans once its result is out: they may come a moment later

    def whole(spans: list[ReceivedSpan]) -> bool:
        return all(set(trace) == ROBOT | NETAPP for trace in by_trace(spans).values())

    traces = by_trace(otlp.wait_for(whole))
    assert len(traces) <= 3  # 20 frames at 1 %: almost surely none; each one sampled is whole on both sides
    assert all(trace["frame"].service == "robot" for trace in traces.values())
    robot_tracer.shutdown()


def test_5g_era_robots_without_trace_context_are_served_and_sampled_by_the_netapp(otlp, traced_netapp, jpeg):
    server, netapp_tracer = traced_netapp
    robot = RawRobot(server.url)
    try:
        assert robot.init()[0] is True
        robot.frame({"timestamp": 1, "frame": jpeg})  # as 5G-ERA sends it: no metadata at all
        assert robot.next("results")["timestamp"] == 1
        bad = {"traceparent": "00-" + "0" * 32 + "-" + "1" * 16 + "-01", "tracestate": "x" * 10_000}
        robot.frame({"timestamp": 2, "frame": jpeg, "metadata": bad})  # malformed: ignored, as W3C says
        second = robot.next("results")
        assert second["timestamp"] == 2 and second["detections"]
    finally:
        robot.close()
    assert "netapp_trace_context_ignored_total 1.0" in requests.get(f"{server.url}/metrics", timeout=5).text
    netapp_tracer.flush()
    traces = by_trace(otlp.wait_for(lambda spans: len(spans) >= 2 * len(NETAPP)))
    assert len(traces) == 2
    for trace in traces.values():
        assert set(trace) == NETAPP
        assert trace["netapp.frame"].parent_id == ""  # a root: its own sampler's decision (parent-based: on)


def test_tracing_is_off_and_the_sdk_not_even_imported_without_an_endpoint():
    code = (
        "import sys\n"
        "from netapp.server.services import NetAppServices\n"
        "from netapp.client import NetAppClient\n"
        "from netapp.tracing import tracer_from_env\n"
        "from netapp.server.settings import Settings\n"
        "from tests.support.sample_processor import MeanColour\n"
        "services = NetAppServices.build(MeanColour(), Settings())\n"
        "assert services.pipeline.tracing is None and tracer_from_env('netapp-robot') is None\n"
        "assert not [m for m in sys.modules if m.startswith('opentelemetry.sdk')], 'the SDK was imported'\n"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("OTEL_")}  # no endpoint: off
    env.update(PYTHONPATH=str(ROOT), OTEL_TRACES_SAMPLER="always_on")
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr[-2000:]


STREAM = ["stream", "http://127.0.0.1:9", "--source", "missing.jpg"]


@pytest.mark.parametrize(
    "command", [["serve", "--model", "missing.onnx", "--port", "0"], ["middleware"], ["operator"], STREAM]
)
def test_a_wrong_otel_variable_stops_each_command_with_one_line(command):
    env = {k: v for k, v in os.environ.items() if not k.startswith("OTEL_")}
    env.update(PYTHONPATH=f"{ROOT}:{ROOT / 'operator'}", OTEL_EXPORTER_OTLP_ENDPOINT="http://127.0.0.1:9")
    env.update(OTEL_TRACES_SAMPLER="traceidratio", OTEL_TRACES_SAMPLER_ARG="3")
    done = subprocess.run(
        [sys.executable, "-m", "netapp", *command], env=env, capture_output=True, text=True, timeout=60, cwd=ROOT
    )
    assert done.returncode == 2
    assert "OTEL_TRACES_SAMPLER_ARG=3: give a number in [0, 1]" in done.stderr and "Traceback" not in done.stderr


@pytest.mark.parametrize(
    "variable, words",
    [
        (("OTEL_EXPORTER_OTLP_PROTOCOL", "grpc"), "OTEL_EXPORTER_OTLP_PROTOCOL=grpc: set http/protobuf"),
        (("OTEL_TRACES_SAMPLER", "bogus"), "OTEL_TRACES_SAMPLER=bogus: use one of"),
    ],
)
def test_netapp_stream_says_a_wrong_otel_setting_in_one_line(variable, words, monkeypatch, capsys):
    from netapp.cli import main

    for name in [k for k in os.environ if k.startswith("OTEL_")]:
        monkeypatch.delenv(name)
    monkeypatch.setenv("OTEL_EXPORTER_OTLP_ENDPOINT", "http://127.0.0.1:9")
    monkeypatch.setenv(*variable)
    assert main(STREAM) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and words in err[0], err


def test_configured_without_the_sdk_it_runs_untraced_and_says_what_to_install():
    code = (
        "import sys, logging\n"
        "sys.modules['opentelemetry.sdk'] = None  # as if the extra were not installed\n"
        "logging.basicConfig()\n"
        "from netapp.server.services import NetAppServices\n"
        "from netapp.server.settings import Settings\n"
        "from tests.support.sample_processor import MeanColour\n"
        "assert NetAppServices.build(MeanColour(), Settings()).pipeline.tracing is None\n"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("OTEL_")}
    env.update(PYTHONPATH=str(ROOT), OTEL_EXPORTER_OTLP_ENDPOINT="http://127.0.0.1:9")
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "pip install 'netapp-toolkit[tracing]'" in done.stderr
