"""OpenTelemetry traces, off unless configured (docs/tracing.md); shared by the netapp, the robot client, the
middleware and the operator (no server code).

Configured by the standard variables: `OTEL_EXPORTER_OTLP_ENDPOINT` (or `OTEL_EXPORTER_OTLP_TRACES_ENDPOINT`) turns
it on, `OTEL_TRACES_SAMPLER` and `OTEL_TRACES_SAMPLER_ARG` choose what is sampled, `OTEL_SERVICE_NAME` names the
process; `OTEL_SDK_DISABLED=true` or `OTEL_TRACES_EXPORTER=none` turn it off. Without an endpoint nothing is
imported: the SDK and the OTLP exporter are the optional extra `tracing`.

Spans are made after the fact from timestamps the data path takes anyway (`SpanRecord`: a name, ids, a start and
an end), never by wrapping hot code in context managers: a frame that is not sampled costs a traceparent's parsing,
one that is costs a few `ReadableSpan`s handed to the SDK's batch processor, which exports them on its own thread.
The robot's root span id must be known before the span ends (it travels in the traceparent), so ids are chosen
here rather than by the SDK's tracer.
"""

from __future__ import annotations

import atexit
import logging
import os
import threading
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from netapp import __version__
from netapp.tracecontext import TraceContext

log = logging.getLogger(__name__)

SAMPLERS = (
    "always_on",
    "always_off",
    "traceidratio",
    "parentbased_always_on",
    "parentbased_always_off",
    "parentbased_traceidratio",
)
DEFAULT_SAMPLER = "parentbased_always_on"  # the specification's default
PROTOCOL = "http/protobuf"  # the one OTLP protocol exported here (port 4318)
DEFAULT_SCHEDULE_DELAY_MS = 5000.0
EXTRA_HINT = "pip install 'netapp-toolkit[tracing]'"
KINDS = ("internal", "server", "client")


@dataclass(frozen=True)
class TraceConfig:
    """What the OTel variables say; `from_env` returns None when tracing is off."""

    endpoint: str  # the OTLP/HTTP traces URL (…/v1/traces)
    service_name: str
    sampler: str = DEFAULT_SAMPLER
    ratio: float = 1.0  # traceidratio samplers' probability
    schedule_delay_ms: float = DEFAULT_SCHEDULE_DELAY_MS  # the batch processor's export period

    @classmethod
    def from_env(cls, default_service: str, env: Mapping[str, str] | None = None) -> TraceConfig | None:
        """The configuration the variables give (None: off); ValueError saying which variable is wrong."""
        env = os.environ if env is None else env
        if env.get("OTEL_SDK_DISABLED", "").strip().lower() == "true":
            return None
        if env.get("OTEL_TRACES_EXPORTER", "otlp").strip().lower() in ("none", ""):
            return None
        endpoint = env.get("OTEL_EXPORTER_OTLP_TRACES_ENDPOINT", "").strip()
        if not endpoint and (base := env.get("OTEL_EXPORTER_OTLP_ENDPOINT", "").strip()):
            endpoint = base.rstrip("/") + "/v1/traces"
        if not endpoint:
            return None
        protocol = env.get("OTEL_EXPORTER_OTLP_TRACES_PROTOCOL") or env.get("OTEL_EXPORTER_OTLP_PROTOCOL") or PROTOCOL
        if protocol.strip().lower() != PROTOCOL:
            raise ValueError(f"OTEL_EXPORTER_OTLP_PROTOCOL={protocol}: set {PROTOCOL} (port 4318), the one exported")
        sampler = env.get("OTEL_TRACES_SAMPLER", DEFAULT_SAMPLER).strip().lower() or DEFAULT_SAMPLER
        if sampler not in SAMPLERS:
            raise ValueError(f"OTEL_TRACES_SAMPLER={sampler}: use one of {', '.join(SAMPLERS)}")
        ratio = _number(env, "OTEL_TRACES_SAMPLER_ARG", 1.0, 0.0, 1.0) if sampler.endswith("traceidratio") else 1.0
        delay = _number(env, "OTEL_BSP_SCHEDULE_DELAY", DEFAULT_SCHEDULE_DELAY_MS, 1.0, 3_600_000.0)
        service = env.get("OTEL_SERVICE_NAME", "").strip() or default_service
        return cls(endpoint, service, sampler, ratio, delay)


def _number(env: Mapping[str, str], name: str, default: float, low: float, high: float) -> float:
    raw = env.get(name, "").strip()
    if not raw:
        return default
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not low <= value <= high:
        raise ValueError(f"{name}={raw}: give a number in [{low:g}, {high:g}]")
    return value


@dataclass(slots=True)
class SpanRecord:
    """One span, made after the fact: ids, times (Unix ns) and what it is about. `parent_id` 0: a root span;
    `remote_parent`: the parent is another process's (the robot's, for the netapp's frame span)."""

    name: str
    span_id: int
    parent_id: int
    start_ns: int
    end_ns: int
    kind: str = "internal"
    attributes: dict[str, Any] = field(default_factory=dict)
    error: str | None = None  # the span failed, and why
    remote_parent: bool = False


def wall_minus_monotonic_ns() -> int:
    """This process's wall clock minus its monotonic clock: monotonic stamps + this = Unix time."""
    return time.time_ns() - time.monotonic_ns()


class TracingUnavailable(RuntimeError):
    """Tracing is configured but the SDK is not installed."""


class Tracer:
    """The SDK's sampler and batch exporter behind three calls: `sample`, `emit`, `flush`. Thread-safe."""

    def __init__(self, config: TraceConfig) -> None:
        try:
            from opentelemetry import trace as api
            from opentelemetry.exporter.otlp.proto.http.trace_exporter import OTLPSpanExporter
            from opentelemetry.sdk import trace as sdk
            from opentelemetry.sdk.resources import SERVICE_NAME, Resource
            from opentelemetry.sdk.trace import sampling
            from opentelemetry.sdk.trace.export import BatchSpanProcessor
            from opentelemetry.sdk.util.instrumentation import InstrumentationScope
        except ImportError as exc:
            message = f"tracing is configured (OTEL_EXPORTER_OTLP_ENDPOINT) but {exc}: {EXTRA_HINT}"
            raise TracingUnavailable(message) from exc
        self.config = config
        self._api, self._sdk = api, sdk
        self._resource = Resource.create({SERVICE_NAME: config.service_name})
        self._scope = InstrumentationScope("netapp", __version__)
        self._sampler = _sampler(sampling, config)
        self._parent_based = config.sampler.startswith("parentbased_")
        self._kinds = {"internal": api.SpanKind.INTERNAL, "server": api.SpanKind.SERVER, "client": api.SpanKind.CLIENT}
        self._error = sdk.Status(api.StatusCode.ERROR)
        self._processor = BatchSpanProcessor(
            OTLPSpanExporter(endpoint=config.endpoint), schedule_delay_millis=config.schedule_delay_ms
        )

    @property
    def service_name(self) -> str:
        return self.config.service_name

    def sample(self, trace_id: int, parent: TraceContext | None, name: str) -> bool:
        """Whether a span of `trace_id` under `parent` (None: a root) is sampled, by the configured sampler."""
        if parent is not None and self._parent_based:
            return parent.sampled  # what ParentBased decides for a remote parent, without building a Context
        context = None
        if parent is not None:
            api = self._api
            remote = api.SpanContext(parent.trace_id, parent.span_id, True, api.TraceFlags(int(parent.sampled)))
            context = api.set_span_in_context(api.NonRecordingSpan(remote))
        return self._sampler.should_sample(context, trace_id, name).decision.is_sampled()

    def emit(self, trace_id: int, spans: Iterable[SpanRecord], tracestate: str = "") -> None:
        """Hand finished spans of one trace to the exporter (queued; exported on its thread)."""
        api, sdk = self._api, self._sdk
        flags = api.TraceFlags(api.TraceFlags.SAMPLED)
        state = api.TraceState.from_header([tracestate]) if tracestate else None
        for span in spans:
            if span.error:
                span.attributes["error.type"] = span.error
            context = api.SpanContext(trace_id, span.span_id, False, flags, state)
            parent = (
                api.SpanContext(trace_id, span.parent_id, span.remote_parent, flags, state) if span.parent_id else None
            )
            readable = sdk.ReadableSpan(
                span.name,
                context=context,
                parent=parent,
                resource=self._resource,
                attributes=span.attributes,
                kind=self._kinds[span.kind],
                status=self._error if span.error else sdk.Status(api.StatusCode.UNSET),
                start_time=span.start_ns,
                end_time=max(span.start_ns, span.end_ns),
                instrumentation_scope=self._scope,
            )
            self._processor.on_end(readable)

    def flush(self, timeout_s: float = 5.0) -> bool:
        """Export what is queued now; whether it all went within `timeout_s`."""
        return self._processor.force_flush(int(timeout_s * 1000))

    def shutdown(self) -> None:
        self._processor.shutdown()


def _sampler(sampling: Any, config: TraceConfig) -> Any:
    """The SDK's sampler for `config.sampler` (the names of the OTEL_TRACES_SAMPLER specification)."""
    ratio = config.ratio
    return {
        "always_on": lambda: sampling.ALWAYS_ON,
        "always_off": lambda: sampling.ALWAYS_OFF,
        "traceidratio": lambda: sampling.TraceIdRatioBased(ratio),
        "parentbased_always_on": lambda: sampling.ParentBased(sampling.ALWAYS_ON),
        "parentbased_always_off": lambda: sampling.ParentBased(sampling.ALWAYS_OFF),
        "parentbased_traceidratio": lambda: sampling.ParentBasedTraceIdRatio(ratio),
    }[config.sampler]()


_from_env: dict[str, Tracer | None] = {}
_from_env_lock = threading.Lock()


def tracer_from_env(default_service: str) -> Tracer | None:
    """The process's tracer as the OTel variables configure it (one per service name, shared by every user in the
    process, flushed at exit); None when tracing is off, or configured without the SDK (logged once, with the
    install hint). ValueError for a variable with a wrong value."""
    with _from_env_lock:
        if default_service in _from_env:
            return _from_env[default_service]
        config = TraceConfig.from_env(default_service)
        tracer = None
        if config is not None:
            try:
                tracer = Tracer(config)
            except TracingUnavailable as exc:
                log.warning("%s", exc)
            else:
                atexit.register(tracer.shutdown)
                log.info("tracing to %s as %s (%s)", config.endpoint, config.service_name, config.sampler)
        _from_env[default_service] = tracer
        return tracer
