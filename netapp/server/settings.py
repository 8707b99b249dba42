"""Server settings: one dataclass, filled from the command line or by code, and the plain values it holds (a camera's
spec, a rollout's policy and shadowing: frozen dataclasses that check themselves, nothing more). The features that
use them import them from here; Settings imports no feature (tests/test_import_cycles.py)."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from urllib.parse import urlsplit, urlunsplit

from netapp.broker.address import BrokerAddress
from netapp.protocol import DEFAULT_PRIORITY, OPEN_ADMISSION, PRIORITY_CLASSES
from netapp.webrtc_ice import IceServer

# Each class's weight (low, normal, high) when classes compete for the inference threads: with all three waiting low
# gets 1/7 of the time, normal 2/7, high 4/7; with high and low alone, 4/5 and 1/5 (netapp.server.pipeline.priorities).
DEFAULT_WEIGHTS = (1.0, 2.0, 4.0)


@dataclass(frozen=True)
class SourceSpec:
    """A camera the netapp pulls (`--source NAME=rtsp://...`, parsed by `netapp.server.sources.naming`)."""

    name: str
    url: str  # what FFmpeg opens: the camera's URL without our fragment
    transport: str = "auto"

    @property
    def shown_url(self) -> str:
        """The URL without its credentials, for logs and pages (rtsp://user:pass@host is common)."""
        parts = urlsplit(self.url)
        return urlunsplit((parts.scheme, parts.netloc.rpartition("@")[2], parts.path, parts.query, ""))


@dataclass(frozen=True)
class Policy:
    """When a candidate is promoted or rolled back (`netapp serve --candidate`'s flags)."""

    promote_after: int = 200  # frames compared, each phase, before the next one
    min_agreement: float = 0.95  # F1 of matched boxes (or top-1 agreement) over the window
    max_slowdown: float = 1.5  # candidate time / current time on the median frame, both timed alike
    window: int = 50  # the latest frames compared that agreement and p95 are judged over
    max_errors: int = 0  # candidate failures tolerated
    canary_share: float = 0.0  # share of robots given the candidate's results after the shadow; 0: no canary

    def problem(self) -> str | None:
        """What is wrong with these values, in one line; None when they are usable."""
        if self.promote_after < 1:
            return "promote_after must be 1 or more frames"
        if not 0.0 <= self.min_agreement <= 1.0:
            return "min_agreement must be between 0 and 1"
        if not (math.isfinite(self.max_slowdown) and self.max_slowdown >= 1.0):
            return "max_slowdown must be 1 or more (the candidate's p95 over the current model's)"
        if self.window < 1:
            return "window must be 1 or more frames"
        if self.max_errors < 0:
            return "max_errors must be 0 or more"
        if not 0.0 <= self.canary_share < 1.0:
            return "canary_share must be at least 0 and below 1 (0: no canary)"
        return None

    @property
    def judged_after(self) -> int:
        """Frames compared before agreement and speed are judged at all (a few frames say little)."""
        return min(self.window, self.promote_after)


DEFAULT_SAMPLE = 0.1  # share of frames the candidate sees
DEFAULT_BUDGET = 0.1  # the shadow's time (candidate and current model), as a share of the current model's time


@dataclass(frozen=True)
class Shadowing:
    """How much of the traffic the candidate sees."""

    sample: float = DEFAULT_SAMPLE
    budget: float = DEFAULT_BUDGET

    def problem(self) -> str | None:
        if not 0.0 < self.sample <= 1.0:
            return "shadow_sample must be above 0 and at most 1 (the share of frames the candidate sees)"
        if not 0.0 < self.budget <= 10.0:
            return "shadow_budget must be above 0 and at most 10 (the candidate's time over the current model's)"
        return None


def default_prepare_threads() -> int:
    """Decoding beside inference pays only with spare cores: where onnxruntime already uses every core (CPU
    inference on two), a decode thread preempts one of its workers and the whole inference waits for it, so
    decoding then runs on the inference thread itself (measured: docs/benchmarks.md#what-the-knobs-do)."""
    return 0 if (os.cpu_count() or 1) <= 2 else 2


def default_lanes() -> int:
    """Two batches at once keep both cores of a 2-core machine busy: one onnxruntime call alone leaves gaps between
    its parallel operators (measured: docs/benchmarks.md#many-robots, about +40 % results per second with
    many robots, while one robot alone still gets every core for its frame)."""
    return 2 if (os.cpu_count() or 1) >= 2 else 1


@dataclass
class Settings:
    max_payload_bytes: int = 8 * 1024 * 1024  # one frame; larger gets 413 / data_error
    # pixels of one picture, read from its header before decoding (JPEG SOF, H.264 SPS); more gets 413 / data_error.
    # 4096x2304: 4K UHD (3840x2160, 8.3 Mpx) with 14 % to spare; a decoded 4K BGR picture takes 25 MB.
    max_pixels: int = 4096 * 2304
    queue_size: int = 1  # frames waiting per session; newest wins, older ones are dropped and counted
    results_buffer: int = 100  # results kept for HTTP polling per session; older ones are dropped and counted
    session_ttl_s: float = 300.0  # an HTTP session idle this long is closed
    live_session_s: float = 30.0  # an HTTP session idle this long no longer counts against max_sessions
    wait_timeout_s: float = 30.0  # longest `POST /send_image?wait=true` waits for its result
    # decode + preprocess threads beside the inference thread; 0: on the inference thread, before each batch
    prepare_threads: int = field(default_factory=default_prepare_threads)
    max_batch: int = 0  # frames from different robots per inference; 0: what the processor allows
    # OpenCV's own threads for one decode or resize: the lanes and the prepare pool already decode side by side, and
    # a second thread for a 640x480 resize cost 0.5 ms of CPU a frame for no time saved (docs/benchmarks.md)
    opencv_threads: int = 1
    # batches processed at once by a stateless processor (one model, one set of weights, called from this many
    # threads); a stateful one always has one lane, so each session's state is updated in frame order
    lanes: int = field(default_factory=default_lanes)
    state_dir: str | None = None  # where SAVE_STATE / LOAD_STATE keep session states (a volume); None: refused
    # Caps on what anyone who reaches the port can make the netapp hold (the operator's default limit is 512Mi); see
    # docs/security.md#limits.
    # CPU seconds per second one H.264 stream may spend decoding (bursts of 2 s); past it the stream skips to its
    # next keyframe (`h264_overloaded`), so a robot flooding large keyframes cannot take the cores inference needs.
    # 0.25 decodes 1080p at 30 FPS (~0.1 s/s) with room, 4K at ~10 FPS; on 2 cores it leaves inference 7/8.
    h264_decode_share: float = 0.25
    max_sessions: int = 64  # open sessions, all transports; past it /register and INIT get 503 / command_error
    max_register_bytes: int = 64 * 1024  # the /register body (robot id and args); larger gets 413
    # `POST /send_image?wait=true` requests waiting at once, in all and per session (newest wins: a session's
    # older frames are superseded anyway); past either, 503 + Retry-After
    max_waiting: int = 64
    max_waiting_per_session: int = 4
    # open connections and requests (uvicorn limit_concurrency); past it 503. Idle ones count too, closed after
    # head_timeout_s: room for 1,500 idle connections beside the robots.
    max_connections: int = 2048
    max_attachments: int = 4  # binary attachments of one Socket.IO packet (a frame has 1); past it: disconnected
    head_timeout_s: float = 10.0  # a connection must send a complete request head (line + headers) within this
    body_timeout_s: float = 30.0  # a frame's body must arrive within this; else 408
    # SHA-256 (hex) of the bearer token robots must send (netapp.server.access); None: no token needed
    token_sha256: str | None = None
    # SHA-256 (hex) of a token that may start a rollout (POST /rollout) besides the netapp's token and cluster key
    admin_token_sha256: str | None = None
    # Priority classes (docs/scaling.md#priorities): the class of a robot that presents no class token, and the
    # highest it may claim; the SHA-256 (hex) of each class token -> the highest class its robots may claim
    robot_priority: int = PRIORITY_CLASSES.index(DEFAULT_PRIORITY)
    priority_tokens: dict[str, int] = field(default_factory=dict)
    # each class's weight when classes compete for the inference threads (`netapp.server.pipeline.priorities`)
    priority_weights: tuple[float, ...] = DEFAULT_WEIGHTS
    # each result tells its robot when its next frame will be taken (docs/client.md#the-next-turn-hint); off: as a
    # netapp before the hint (robots pace on the excess wait), for comparisons
    next_turn_hint: bool = True
    keep_alive_s: int = 5  # an idle keep-alive connection is closed after this (uvicorn timeout_keep_alive)
    # Replicas (netapp.server.cluster.ownership): the key they share signs session ids that name their owner; without
    # it a replica is on its own. advertise_url is how the other replicas reach this one (http://POD_IP:PORT).
    cluster_key: bytes | None = field(default=None, repr=False)
    advertise_url: str | None = None
    # PEM file the other replicas' certificates are verified against when they advertise https:// (`netapp serve
    # --peer-ca`, else its own --tls-cert; docs/security.md#tls-between-replicas); None: the system's CAs
    peer_ca: str | None = None
    drain_grace_s: float = 20.0  # after SIGTERM: longest wait for the robots to move before exiting
    # capacity (netapp.server.capacity): the hard limit leaves each robot this share of its input rate; 0: no limit
    hard_share: float = 0.5
    # who is admitted (docs/scaling.md#admission): "open", robots up to max_sessions share the capacity; "measured",
    # a robot past the measured hard limit is refused too (something else places it)
    admission: str = OPEN_ADMISSION
    warm_batches: int = 50  # batches measured before the estimate may refuse anyone (the first ones run cold)
    assumed_robot_fps: float = 10.0  # a robot's input rate until robots stream (the published limits use it)
    # the 5G-ERA heartbeat: POST {middleware_address}/status/netapp every second (5G-ERA injects these as env vars)
    middleware_address: str | None = None
    netapp_id: str | None = None
    netapp_name: str | None = None
    # cameras the netapp pulls itself (`--source NAME=rtsp://...`; docs/cameras.md)
    sources: tuple[SourceSpec, ...] = ()
    # where the netapp writes the cameras' results itself, one rotating JSON-lines file per camera (`--source-results`)
    source_results: str | None = None
    source_results_bytes: int = 64 * 1024 * 1024
    # brokers every result is published to (`--publish URL`; docs/broker.md)
    publish: tuple[BrokerAddress, ...] = ()
    # brokers whose work queue the netapp takes robots' frames from (`--consume URL`; docs/broker.md)
    consume: tuple[BrokerAddress, ...] = ()
    # a candidate model to roll out once the current one is loaded (`--candidate`; docs/rollouts.md), its sha256, and
    # how it is judged and how much traffic it sees
    candidate: str | None = None
    candidate_sha256: str | None = None
    rollout_policy: Policy = field(default_factory=Policy)
    shadowing: Shadowing = field(default_factory=Shadowing)
    # H.264 over RTP pushed to a session's UDP port (`--rtp-ports`; docs/cameras.md#rtp-push); None: refused
    rtp_ports: range | None = None
    rtp_host: str = "127.0.0.1"  # the address the RTP ports are bound on (`netapp serve --host`)
    rtp_max_packets_per_s: float = 5000.0  # per session: 1080p30 H.264 at 8 Mbit/s is about 700 packets/s
    rtp_max_bytes_per_s: float = 5_000_000.0  # per session (40 Mbit/s); past either bound, datagrams are dropped
    # with several replicas: the namespace of the Leases that give each camera to one replica (`--camera-leases`)
    camera_leases: str | None = None
    # WebRTC peers (`POST /webrtc/offer`, the `webrtc` extra; docs/cameras.md#webrtc): the STUN/TURN servers named
    # (none: none is contacted), the host candidates offered (empty: every address but loopback), and the bounds
    webrtc_ice_servers: tuple[IceServer, ...] = ()
    webrtc_addresses: tuple[str, ...] = ("127.0.0.1",)
    webrtc_max_peers: int = 16
    webrtc_max_peers_per_client: int = 4  # per address the offers come from
    webrtc_max_sdp_bytes: int = 16 * 1024
    webrtc_connect_timeout_s: float = 10.0  # from the answer to a connected peer

    @property
    def transport_limit_bytes(self) -> int:
        """Largest Socket.IO message the transport reads. Past the frame limit but below this, the robot gets a
        data_error naming the limit; past this, the connection is closed (WebSocket 1009), bounding memory."""
        return 2 * self.max_payload_bytes + 64 * 1024
