"""What a NetApp runs, whichever backend runs it (pure): its parsed spec as `netapp serve`'s argv and environment.

The operator wraps the command in a container (`render.render_deployment`, which adds around it only what a
cluster has: `render.CLUSTER_ONLY_ARGS` and `render.CLUSTER_ONLY_ENV`); the middleware's local backend runs it as
a process on this machine (`netapp_middleware/backends/local.py`). Each runtime says where it listens and where
the netapp's files are (`Where`); the spec decides everything else, the same way for both. What one machine cannot
give a spec is refused by `one_machine_refusal`, one line naming the field as the user wrote it, never ignored.
"""

from __future__ import annotations

import dataclasses

from netapp.protocol import AUTO_DEVICE, DEFAULT_PRIORITY, GPU_DEVICES, OPEN_ADMISSION, PRIORITY_CLASSES
from netapp_operator.publish import CONSUME, publish_args
from netapp_operator.rtp import rtp_args
from netapp_operator.spec import ENGINE_CACHE_DIR, STATE_DIR, NetAppSpec, source_args
from netapp_operator.webrtc import WebRtcSpec, webrtc_args


@dataclasses.dataclass(frozen=True)
class Where:
    """Where the netapp listens and keeps its files on the runtime that runs it."""

    host: str
    port: int
    model_file: str | None = None  # the model, already here (fetched or mounted); None: the netapp fetches its url
    state_dir: str = STATE_DIR  # spec.state's volume
    trt_cache_dir: str = ENGINE_CACHE_DIR  # spec.engineCache's (or the tensorrt device's) volume
    # the runtime's own flags, after --port: a cluster's drain, camera leases and TLS (render.CLUSTER_ONLY_ARGS)
    runtime_args: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class ServeCommand:
    """`netapp serve`'s arguments (after `serve`) and the environment the spec gives it."""

    args: list[str]
    env: dict[str, str]


def serve_command(spec: NetAppSpec, where: Where, webrtc: WebRtcSpec | None = None) -> ServeCommand:
    """The arguments and environment that serve `spec` at `where`; `webrtc` in place of `spec.webrtc` (the operator's
    default for a NetApp without one). The spec's own `args` come last, so that they win."""
    webrtc = spec.webrtc if webrtc is None else webrtc
    args = [
        *_model_args(spec, where),
        *(["--state-dir", where.state_dir] if spec.state is not None else []),
        *_device_args(spec, where),
        *("--host", where.host, "--port", str(where.port)),
        *where.runtime_args,
        # the netapp's own default is open: only another choice is rendered
        *(("--admission", str(spec.admission)) if spec.admission != OPEN_ADMISSION else ()),
        *_priority_args(spec),
        *source_args(spec.sources),
        *rtp_args(spec.rtp),
        *webrtc_args(webrtc),
        *publish_args(spec.publish),
        *publish_args(spec.consume, CONSUME),
        *[str(a) for a in spec.args],
    ]
    return ServeCommand(args, serve_env(spec))


def serve_env(spec: NetAppSpec) -> dict[str, str]:
    """The environment `spec.env` gives the netapp (the runtime's own variables aside)."""
    return {str(item["name"]): str(item.get("value", "")) for item in spec.env}


def _model_args(spec: NetAppSpec, where: Where) -> list[str]:
    """What it serves: a `package.module:Class` alone (it loads its own weights), else a built-in name in front of
    its model: the runtime's file, or the spec's url that the netapp fetches and checks itself."""
    if spec.custom_processor:
        return ["--processor", spec.custom_processor]
    named = ["--processor", str(spec.processor)] if spec.processor else []
    model = spec.model
    if where.model_file:
        return [*named, "--model", where.model_file]
    if model is None or not model.url:
        return named
    sha256 = ["--sha256", str(model.sha256)] if model.sha256 else []
    return [*named, "--model", str(model.url), *sha256, "--download-timeout", str(model.timeout_seconds)]


def _device_args(spec: NetAppSpec, where: Where) -> list[str]:
    """Where the model runs: `--device` (auto, the netapp's own default, renders none), `--fp16`, TensorRT's cache."""
    args = [] if spec.device == AUTO_DEVICE else ["--device", str(spec.device)]
    if spec.fp16:
        args.append("--fp16")
    return [*args, "--trt-cache", where.trt_cache_dir] if spec.trt_cache is not None else args


def _priority_args(spec: NetAppSpec) -> list[str]:
    """`spec.priority` as the netapp's flags (its own defaults, normal robots, no class token and the default weights,
    render none)."""
    robots = [] if spec.priority.robots == DEFAULT_PRIORITY else ["--robot-priority", str(spec.priority.robots)]
    tokens = (["--priority-token", f"{c}={d}"] for c, d in sorted(spec.priority.token_sha256.items()))
    given = [f"{c}={spec.priority.weights[c]:g}" for c in PRIORITY_CLASSES if c in spec.priority.weights]
    weights = ["--priority-weights", ",".join(given)] if given else []
    return [*robots, *(arg for pair in tokens for arg in pair), *weights]


# A container's, not the netapp's: a process on one machine runs this machine's netapp on a free port, unlimited.
CONTAINER_FIELDS = ("spec.image", "spec.port", "spec.resources.cpu", "spec.resources.memory")


def one_machine_refusal(spec: NetAppSpec, *, gpu: bool) -> str | None:
    """Why one machine running `spec` as one process cannot do what it says, in one line naming the field as the
    user wrote it; None when it can. `gpu`: whether this machine has one. The spec's own problems come first
    (but those of `CONTAINER_FIELDS`).

    Honoured here: the model's url, processor, device (a GPU one with a GPU), fp16, admission, priority, sources, rtp,
    webrtc's iceServers, publish and consume (a broker without a Secret), args, env, and the claims the netapp writes
    (state, engineCache), each a directory of the runtime named after the claim. A container's image, port and
    resources are the runtime's, not the netapp's."""
    problems = [p for p in spec.problems if not p.startswith(CONTAINER_FIELDS)]
    if problems:
        return problems[0]
    needs_cluster = [
        (spec.replicas != 1, f"spec.replicas: {spec.replicas}: one machine runs one netapp process, not replicas"),
        (spec.autoscaling is not None, "spec.autoscaling: scaling replicas needs a cluster"),
        (spec.standby is not None, "spec.standby: a warm copy on another NodePool needs a cluster"),
        (spec.model is not None and spec.model.has_volume, "spec.model.volume: a cluster's volume; give model.url"),
        (spec.tls is not None, "spec.tls.secretName: the certificate is a cluster Secret"),
        (bool(spec.access.require_token), "spec.access.requireToken: the token is a cluster Secret"),
        (spec.webrtc is not None and bool(spec.webrtc.turn_secret), "spec.webrtc.turnSecret: a cluster Secret"),
        (any(b.secret for b in spec.publish), "spec.publish.secret: a broker password is a cluster Secret"),
        (any(b.secret for b in spec.consume), "spec.consume.secret: a broker password is a cluster Secret"),
    ]
    needs_gpu = [
        (spec.placement.require_gpu, "spec.placement.requireGPU"),
        (isinstance(spec.resources.gpus, int) and spec.resources.gpus > 0, "spec.resources.gpus"),
        (spec.device in GPU_DEVICES, f"spec.device: {spec.device}"),
    ]
    if not gpu:
        needs_cluster += [(asked, f"{field} needs a GPU, and this machine has none") for asked, field in needs_gpu]
    return next((reason for refused, reason in needs_cluster if refused), None)
