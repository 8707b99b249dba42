"""Names and numbers of the 5G-ERA wire protocol, shared by the server and the robot client (no server code)."""

from __future__ import annotations

from enum import IntEnum
from typing import Any

DATA_NAMESPACE = "/data"
CONTROL_NAMESPACE = "/control"
COMMAND_EVENT = "command"
COMMAND_ERROR_EVENT = "command_error"
DATA_ERROR_EVENT = "data_error"
RESULTS_EVENT = "results"
IMAGE_EVENT = "image"
H264_EVENT = "image_h264"
# On /control, just before a successful INIT's ack (which keeps 5G-ERA's (ok, message)): what the netapp says of
# the session, e.g. its processor's `input_size` [width, height] (docs/server.md#input-size). 5G-ERA robots ignore it.
SESSION_INFO_EVENT = "session_info"
INPUT_SIZE_FIELD = "input_size"
# ... and the name of the accuracy profile its results follow (netapp/profiles/NAME.json), which an adapting
# robot needs to know what smaller or coarser frames cost (docs/client.md#an-uplink-that-adapts).
ACCURACY_PROFILE_FIELD = "accuracy_profile"
# In a result message (any transport): what the netapp would like next, {"input_size": [w, h], "next_frame_in_ms":
# float}, each key optional (docs/server.md#hints). Other robots ignore the extra key.
HINT_FIELD = "hint"
NEXT_FRAME_FIELD = "next_frame_in_ms"
MOVE_EVENT = "move"  # on /control: this replica is going away; reconnect through the Service ({"reason": ...})
DEFAULT_PORT = 5896
SESSION_HEADER = "X-Session-Id"
FORWARDED_HEADER = "X-Netapp-Forwarded"  # set by a replica forwarding to the owner: never forwarded again
# `reason` of a 503 (and of the `move` event) from a replica that is draining: go to another one (Retry-After).
DRAINING_REASON = "draining"
# `reason` of a refused session (`/register` 503 + Retry-After, a Socket.IO INIT's command_error): the netapp holds
# as many robots as it admits; and of a request or connection without the netapp's token (401, connect_error data).
SESSIONS_FULL_REASON = "sessions_full"
UNAUTHORIZED_REASON = "unauthorized"
# What a robot needs, in results per second, in its INIT data or /register args: the capacity estimate counts it
# at this rate rather than at its camera's (`docs/scaling.md#admission`).
NEEDS_FIELD = "results_per_second"
# A robot's priority class, in its INIT data or /register args (a name, or its index 0..2): under overload higher
# classes go first, the lowest keeps a floor share (`docs/scaling.md#priorities`). A robot may claim a class up to
# the one its token grants (`netapp serve --priority-token CLASS=SHA256`), else up to the netapp's `--robot-priority`.
PRIORITY_FIELD = "priority"
PRIORITY_CLASSES = ("low", "normal", "high")
DEFAULT_PRIORITY = "normal"
# The class tokens' digests, "CLASS=SHA256,CLASS=SHA256" (`netapp serve --priority-token`'s default): how the middleware
# tells a NetApp which tokens grant which class (it hands each robot the token of its class in its robots file).
PRIORITY_TOKENS_ENV = "NETAPP_PRIORITY_TOKENS_SHA256"
# Each class's weight when classes compete, "low=1,normal=2,high=4" (`netapp serve --priority-weights`'s default).
PRIORITY_WEIGHTS_ENV = "NETAPP_PRIORITY_WEIGHTS"
BAD_PRIORITY_REASON = "bad_priority"  # 422: not a class this netapp knows
PRIORITY_NOT_ALLOWED_REASON = "priority_not_allowed"  # 403: above the class the robot's token grants


def parse_priority(value: Any) -> int:
    """A priority class as a robot or a configuration gives it (a name of `PRIORITY_CLASSES`, or its index) -> its
    index; ValueError saying which classes there are."""
    if isinstance(value, str) and value.strip().lower() in PRIORITY_CLASSES:
        return PRIORITY_CLASSES.index(value.strip().lower())
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < len(PRIORITY_CLASSES):
        return value
    shown = repr(value)[:40]
    raise ValueError(
        f"{PRIORITY_FIELD} must be one of {', '.join(PRIORITY_CLASSES)} (or 0 to {len(PRIORITY_CLASSES) - 1}), "
        f"got {shown}"
    )


# The longest Retry-After a netapp asks for (`netapp.server.retry_after`), and the longest a client waits on one: past
# it a robot should rather be placed elsewhere.
MAX_RETRY_AFTER_S = 30
# Who a netapp admits (`netapp serve --admission`, a NetApp's `spec.admission`; docs/scaling.md#admission): "open",
# robots up to --max-sessions share its capacity (the default); "measured", also refused past the measured hard limit.
OPEN_ADMISSION = "open"
MEASURED_ADMISSION = "measured"
ADMISSIONS = (OPEN_ADMISSION, MEASURED_ADMISSION)
# Where a netapp runs its model (`netapp serve --device`, a NetApp's `spec.device`): "auto" takes the best present;
# the GPU ones need an nvidia.com/gpu (the operator requests one) and TensorRT keeps its engines in a cache folder.
AUTO_DEVICE = "auto"
GPU_DEVICES = ("cuda", "tensorrt")
TENSORRT_DEVICE = "tensorrt"
DEVICES = (AUTO_DEVICE, "cpu", *GPU_DEVICES, "openvino")
# `reason` of a frame a newer frame of the same robot superseded in the netapp's queue (newest wins): HTTP 409, or
# a data_error on Socket.IO, so the robot frees that frame's slot at once instead of waiting for a result.
SUPERSEDED_REASON = "superseded"
# How a deployment configures a replica (`netapp serve` reads them; the operator renders them): the key the replicas
# share (from a Secret) and the address the others reach this one at (http://$(POD_IP):PORT).
CLUSTER_KEY_ENV = "NETAPP_CLUSTER_KEY"
ADVERTISE_URL_ENV = "NETAPP_ADVERTISE_URL"
# The CA bundle (a PEM file's path) the other replicas' certificates are verified against when they advertise https://
# (`netapp serve --peer-ca`; without it a replica serving TLS verifies them against its own certificate).
PEER_CA_ENV = "NETAPP_PEER_CA"
# The NetApp a replica belongs to (its cameras' Leases are named after it) and its pod (the downward API's name).
NETAPP_NAME_ENV = "NETAPP_NAME"
POD_NAME_ENV = "POD_NAME"
# The netapp's own monotonic-ns stamps on every result: received, processing started and ended, result sent.
RESULT_STAMPS = ("recv_timestamp", "timestamp_before_process", "timestamp_after_process", "send_timestamp")
# In the result of a frame the netapp traced (docs/tracing.md): its wall clock minus its monotonic clock (ns), so the
# robot can put its own spans on the netapp's timeline with its clock offset estimate. Other robots ignore it.
TRACE_CLOCK_FIELD = "wall_minus_monotonic_ns"
# Every result message's fields; anything else in it is its processor's own output.
RESULT_FIELDS = frozenset({"timestamp", *RESULT_STAMPS, "detections", "dropped", HINT_FIELD, TRACE_CLOCK_FIELD})
# Stateful netapps: an INIT argument asking for the session's state in every Nth result, under this result key.
STATE_CHECKPOINT_ARG = "state_checkpoint_every"
STATE_KEY = "state"
# The environment variable with the SHA-256 (hex) of the bearer token a netapp needs (netapp.server.access); the
# middleware sets it in the NetApp spec of an app that does not allow unauthenticated robots.
TOKEN_DIGEST_ENV = "NETAPP_TOKEN_SHA256"
# SHA-256 of the token that may start a model rollout (POST /rollout) besides the netapp's token and cluster key: what
# the middleware's local backend gives each netapp it starts (docs/rollouts.md)
ADMIN_TOKEN_DIGEST_ENV = "NETAPP_ADMIN_TOKEN_SHA256"
# The bearer token itself: `netapp serve` derives the digest from it (the operator passes a NetApp's token Secret
# this way), `netapp stream` sends it.
TOKEN_ENV = "NETAPP_TOKEN"
# How a robot sends frames: HTTP POSTs of JPEGs, Socket.IO `image` events (JPEG), Socket.IO `image_h264` events,
# or the toolkit's own binary frames on a plain WebSocket (`netapp.framing`, docs/protocol.md; JPEG or H.264).
FRAMES_TRANSPORT = "frames"
# "rtp": H.264 over RTP/UDP, its session, commands and results on the `frames` WebSocket (docs/cameras.md#rtp-push);
# also the INIT argument that asks for it, and the key of the netapp's answer (port, SSRC, SDP)
RTP_TRANSPORT = "rtp"
TRANSPORTS = ("http", "ws", "h264", FRAMES_TRANSPORT, RTP_TRANSPORT)
WEBRTC_TRANSPORT = "webrtc"  # `netapp stream` only: a WebRTC peer of its own (the webrtc extra; netapp.client.webrtc)
FRAMES_H264_LABEL = "frames-h264"  # the netapp's `transport` label of H.264 frames over `frames`
# `reason` of a data_error after which an H.264 sender should restart its stream with a keyframe at once: the
# netapp's decoder lost the stream and would otherwise refuse packets until the next periodic keyframe.
H264_KEYFRAME_REASONS = frozenset(
    {"h264_decode_error", "h264_missing_packet", "h264_no_picture", "h264_waiting_keyframe", "h264_overloaded"}
)
# A robot's deadline for one frame (optional, ignored by netapps that predate it): how long after the netapp
# receives the frame its result may still leave. A netapp that cannot finish the frame by then drops it before
# inference and answers with this `reason` (data_error, or HTTP 504), counted apart from newest-wins drops.
DEADLINE_FIELD = "deadline_ms"  # in the Socket.IO frame message
DEADLINE_HEADER = "X-Deadline-Ms"  # on POST /send_image
DEADLINE_REASON = "deadline"
MAX_DEADLINE_MS = 600_000
# A robot's own uplink/downlink of its previous result, for the netapp's live page (`netapp.server.ui.live`):
# `metadata.latency` in a Socket.IO frame message, this header (the same JSON object) on POST /send_image.
ROBOT_LATENCY_HEADER = "X-Robot-Latency"


def parse_deadline_ms(value: Any) -> float | None:
    """A frame's deadline as received (number, numeric string, or None for none) -> milliseconds; ValueError
    saying what is wrong."""
    if value is None:
        return None
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise ValueError(f"{DEADLINE_FIELD} must be a number of milliseconds, got {value!r}") from None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value <= MAX_DEADLINE_MS:
        raise ValueError(f"{DEADLINE_FIELD} must be a number of milliseconds in (0, {MAX_DEADLINE_MS}], got {value!r}")
    return float(value)


# The name of a camera the netapp pulls itself (`netapp serve --source NAME=rtsp://...`): in WATCH's data, and in the
# results its subscribers get.
SOURCE_FIELD = "source"


# `reason` of a refused WATCH at a replica that does not pull that camera (another holds its Lease): connect again.
ELSEWHERE_REASON = "elsewhere"


# Gauges of a netapp's /metrics that autoscaling reads (the operator renders HPAs and ScaledObjects on them).
METRIC_ROBOTS = "netapp_robots_per_replica"  # robots (open sessions) on the replica
METRIC_LOAD = "netapp_load_ratio"  # robots over the measured optimal limit
METRIC_QUEUE = "netapp_queue_depth"  # frames waiting for inference
METRIC_LATENCY = "netapp_result_latency_seconds"  # receive to result, moving average


class CommandType(IntEnum):
    INIT = 1
    RESET_STATE = 2
    GET_STATE = 3
    SET_STATE = 4
    SAVE_STATE = 5
    LOAD_STATE = 6
    # Not 5G-ERA's: subscribe to a camera the netapp pulls (`data: {"source": NAME}`), its results pushed on `results`
    # with `source` in them (`netapp watch`, docs/cameras.md#results). A connection that watches opens no session.
    WATCH = 7


def error_body(message: str, reason: str, /, **extra: Any) -> dict[str, Any]:
    """The one JSON error body of every HTTP answer that is not 2xx, from the netapp and the middleware alike:
    `error` says what is wrong and what to do, `reason` is a stable machine-readable code (also the `reason`
    label of the rejection metrics), and `extra` carries context such as `timestamp` or `session_id`."""
    return {"error": message, "reason": reason, **extra}


def error_event(timestamp: int | None, message: str, reason: str) -> dict[str, Any]:
    """The one error event of a frame that got no result (or of a message refused before it was read), the same on
    every transport: Socket.IO's `data_error`, the data of the `frames` and WebRTC `error` event, a polled result's
    place. 5G-ERA's `timestamp` and `error`, and `reason` (`error_body`'s code), which lets a robot act on it (restart
    its H.264 stream with a keyframe, for instance)."""
    return {"timestamp": timestamp, "error": message, "reason": reason}


def error_message(body: Any, fallback: str = "") -> str:
    """The message of an error body (see `error_body`), for a client; `fallback` when the body has none."""
    if isinstance(body, dict) and isinstance(body.get("error"), str):
        return body["error"]
    return fallback or str(body)
