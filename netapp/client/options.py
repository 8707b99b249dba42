"""The robot client's options, grouped by what they concern; `NetAppClient`'s keyword arguments fill them in.

* `SessionOptions`: what each netapp session is opened with (identity, args, timeouts, token).
* `SendingOptions`: how frames travel: the transport (`http` | `ws` | `frames`), the codec (`jpeg` | `h264`), the
  in-flight bound, the encoders' settings, pacing and full frames (`send_settings.SendSettings` changes as the robot
  streams). `transport="h264"` is the shorthand for `ws` + `h264`.
* `ServiceOptions`: what the robot needs of the answers: a deadline, a policy over the netapps, a local fallback.
* `AdaptOptions`: whether the uplink adapts (`netapp.client.adapt`), to what latency budget and accuracy floor.
* `Callbacks`: how the robot hears of results, errors and switches.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypedDict

from netapp.accuracy import DEFAULT_F1_FLOOR
from netapp.client.adapt.controller import DEFAULT_BUDGET_MS
from netapp.protocol import RTP_TRANSPORT, STATE_CHECKPOINT_ARG, TRANSPORTS

if TYPE_CHECKING:
    from netapp.client.delivery import Result
    from netapp.client.switching import Switch

# What carries the frames: HTTP POSTs, Socket.IO (5G-ERA), our binary frames, or RTP (its session on frames)
CARRIERS = ("http", "ws", "frames", "rtp")
CODECS = ("jpeg", "h264")  # how each frame is encoded: a JPEG each, or one H.264 stream per netapp
# The uplink adapts (`netapp.client.adapt`), its codec too where the transport carries both; adapts within the
# transport's own codec (before issue 43: the JPEG-only adapter); or frames go as they come.
ADAPT_MODES = ("auto", "auto-one-codec", "off")
H264_SHORTHAND = "h264"  # transport="h264": Socket.IO with the H.264 codec (the netapp counts it as its own transport)


def transport_and_codec(transport: str, codec: str | None) -> tuple[str, str]:
    """The carrier and codec that `transport` (one of `netapp.protocol.TRANSPORTS`) and `codec` (None: the
    transport's own) name; ValueError for a combination that does not exist."""
    if transport not in TRANSPORTS:
        raise ValueError(f"transport must be one of {TRANSPORTS}, got {transport!r}")
    if codec is not None and codec not in CODECS:
        raise ValueError(f"codec must be one of {CODECS}, got {codec!r}")
    if transport == H264_SHORTHAND:
        if codec not in (None, "h264"):
            raise ValueError(f"transport='h264' is Socket.IO with the h264 codec, not {codec!r}")
        return "ws", "h264"
    if transport == RTP_TRANSPORT:
        if codec not in (None, "h264"):
            raise ValueError(f"transport='rtp' carries H.264 only, not {codec!r}")
        return transport, "h264"
    if transport == "http" and codec == "h264":
        raise ValueError("the h264 codec is a stream: it needs transport='ws' or 'frames'")
    return transport, codec or "jpeg"


class ClientKeywords(TypedDict, total=False):
    """`NetAppClient`'s keyword arguments (after the URL and the transport), for type checkers and editors; the
    defaults are `ClientOptions.from_keywords`'s."""

    codec: str | None
    args: dict[str, Any] | None
    robot_id: str | None
    max_in_flight: int
    on_result: Callable[[Result], None] | None
    on_error: Callable[[dict[str, Any]], None] | None
    jpeg_quality: int
    connect_timeout_s: float
    result_timeout_s: float
    h264_options: dict[str, str] | None
    checkpoint_every: int
    token: str | None
    policy: str
    deadline_ms: float | None
    fallback: Any
    on_switch: Callable[[Switch], None] | None
    pacing: bool
    websocket_first: bool
    full_frames: bool
    adapt: str
    latency_budget_ms: float
    accuracy_floor: float
    accuracy_profile: Any
    tracer: Any


@dataclass(frozen=True)
class SessionOptions:
    args: dict[str, Any] = field(default_factory=dict)  # sent with INIT / register (checkpoint_every included)
    robot_id: str | None = None
    token: str | None = field(default=None, repr=False)  # the netapps' bearer token, the same for each
    connect_timeout_s: float = 10.0
    result_timeout_s: float = 10.0  # a frame without an answer this long is lost, freeing its slot
    websocket_first: bool = True  # Socket.IO: no long-polling start (`SessionSettings`)


@dataclass(frozen=True)
class SendingOptions:
    transport: str = "ws"  # http, ws or frames
    codec: str = "jpeg"  # jpeg or h264
    max_in_flight: int = 2
    jpeg_quality: int = 85
    h264_options: dict[str, str] | None = None
    pacing: bool = True  # hold frames back while a netapp is the bottleneck (`netapp.client.pacing`)
    full_frames: bool = False  # send frames at their own size, not fitted to the netapp's processor


@dataclass(frozen=True)
class ServiceOptions:
    deadline_ms: float | None = None
    policy: str = "primary"
    fallback: Any = None  # an SDK Processor run on the robot while no netapp meets the deadline
    tracer: Any = None  # a `netapp.tracing.Tracer` for frame traces; None: as the OTel variables say (docs/tracing.md)


@dataclass(frozen=True)
class AdaptOptions:
    mode: str = "off"  # "auto": choose size, quality (or bitrate) and frame rate from the uplink's measurements
    latency_budget_ms: float = DEFAULT_BUDGET_MS
    accuracy_floor: float = DEFAULT_F1_FLOOR  # the least F1 against full quality (`netapp.accuracy`)
    profile: Any = None  # an `AccuracyProfile` or a shipped profile's name; None: YOLOX-Nano's


@dataclass(frozen=True)
class Callbacks:
    on_result: Callable[[Result], None] | None = None
    on_error: Callable[[dict[str, Any]], None] | None = None
    on_switch: Callable[[Switch], None] | None = None


@dataclass(frozen=True)
class ClientOptions:
    """All of a client's options, by group."""

    session: SessionOptions
    sending: SendingOptions
    service: ServiceOptions
    callbacks: Callbacks
    adapt: AdaptOptions = AdaptOptions()

    @classmethod
    def from_keywords(
        cls,
        transport: str = "ws",
        *,
        codec: str | None = None,
        args: dict[str, Any] | None = None,
        robot_id: str | None = None,
        max_in_flight: int = 2,
        on_result: Callable[[Result], None] | None = None,
        on_error: Callable[[dict[str, Any]], None] | None = None,
        jpeg_quality: int = 85,
        connect_timeout_s: float = 10.0,
        result_timeout_s: float = 10.0,
        h264_options: dict[str, str] | None = None,
        checkpoint_every: int = 0,
        token: str | None = None,
        policy: str = "primary",
        deadline_ms: float | None = None,
        fallback: Any = None,
        on_switch: Callable[[Switch], None] | None = None,
        pacing: bool = True,
        websocket_first: bool = True,
        full_frames: bool = False,
        adapt: str = "off",
        latency_budget_ms: float = DEFAULT_BUDGET_MS,
        accuracy_floor: float = DEFAULT_F1_FLOOR,
        accuracy_profile: Any = None,
        tracer: Any = None,
    ) -> ClientOptions:
        """`NetAppClient`'s keyword arguments, checked and grouped."""
        carrier, codec = transport_and_codec(transport, codec)
        if max_in_flight < 1:
            raise ValueError("max_in_flight must be at least 1")
        if deadline_ms is not None and deadline_ms <= 0:
            raise ValueError("deadline_ms must be positive (or None for no deadline)")
        if adapt not in ADAPT_MODES:
            raise ValueError(f"adapt must be one of {ADAPT_MODES}, got {adapt!r}")
        if not latency_budget_ms > 0:
            raise ValueError("latency_budget_ms must be positive")
        if not 0 <= accuracy_floor <= 1:
            raise ValueError("accuracy_floor is an F1, in 0..1")
        session_args = dict(args or {})
        if checkpoint_every:  # a stateful netapp then puts its session state in every Nth result
            session_args[STATE_CHECKPOINT_ARG] = checkpoint_every
        return cls(
            SessionOptions(session_args, robot_id, token, connect_timeout_s, result_timeout_s, websocket_first),
            SendingOptions(carrier, codec, max_in_flight, jpeg_quality, h264_options, pacing, full_frames),
            ServiceOptions(deadline_ms, policy, fallback, tracer),
            Callbacks(on_result, on_error, on_switch),
            AdaptOptions(adapt, latency_budget_ms, accuracy_floor, accuracy_profile),
        )
