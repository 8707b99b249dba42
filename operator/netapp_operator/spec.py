"""A NetApp's spec, parsed once into a frozen object with the CRD's defaults and the checks a schema cannot make
everywhere (pure).

The CRD schema rejects most bad input at admission, but defaults and CEL rules are not applied by every API server
(nor by test emulators), so the operator applies the same defaults and checks again before it renders anything.
A spec with `problems` is never placed nor rendered; the fields of such a spec keep whatever value they were given.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Mapping
from typing import Any

from netapp.protocol import (
    ADMISSIONS,
    AUTO_DEVICE,
    DEFAULT_PRIORITY,
    DEVICES,
    GPU_DEVICES,
    OPEN_ADMISSION,
    PRIORITY_CLASSES,
    TENSORRT_DEVICE,
)
from netapp.server.sources.naming import parse_sources
from netapp_operator.constants import NETAPP_PORT
from netapp_operator.idle import Scaling, parse_scaling, scaling_problems
from netapp_operator.publish import CONSUME, PublishSpec, parse_publish, publish_problems
from netapp_operator.rtp import RtpSpec, parse_rtp, rtp_problems
from netapp_operator.webrtc import WebRtcSpec, parse_webrtc, webrtc_problems

MODEL_DIR = "/models"
MODEL_FILE = "model.onnx"
MODEL_TIMEOUT_S = 300
STATE_DIR = "/var/lib/netapp/state"  # where a stateful netapp's SAVE_STATE / LOAD_STATE keep states (spec.state)
ENGINE_CACHE_DIR = "/var/cache/netapp/tensorrt"  # TensorRT's built engines (spec.engineCache): `--trt-cache`
ENGINE_CACHE_SIZE = "2Gi"  # an emptyDir cache's sizeLimit when the spec names none (an engine is tens of MB)
_SHA256 = re.compile(r"^[0-9a-fA-F]{64}$")
# `netapp serve --processor`: a built-in name, or package.module:Class installed in the image
PROCESSOR = re.compile(r"^[A-Za-z_][A-Za-z0-9_.-]*(:[A-Za-z_][A-Za-z0-9_]*)?$")
_QUANTITY = re.compile(r"^[0-9]+(\.[0-9]+)?(m|k|Ki|M|Mi|G|Gi|T|Ti|P|Pi|E|Ei)?$")


@dataclasses.dataclass(frozen=True)
class Placement:
    pool: str | None = None  # a NodePool's name: pinned there
    policy: str = "auto"  # edge | cloud | auto (edge, then cloud)
    require_gpu: bool = False


@dataclasses.dataclass(frozen=True)
class Resources:
    cpu: str | None = None
    memory: str | None = None
    gpus: Any = 0


# What `spec.autoscaling` can scale on (each but cpu is a gauge the netapps publish; netapp_operator.autoscaling) and
# what renders it.
AUTOSCALING_METRICS = ("cpu", "robotsPerReplica", "capacityLoad", "queueDepth", "latency")
AUTOSCALING_ENGINES = ("hpa", "keda")


@dataclasses.dataclass(frozen=True)
class Autoscaling:
    max_replicas: Any
    min_replicas: Any = 1
    target_cpu_percent: Any = 70
    metric: Any = "cpu"  # one of AUTOSCALING_METRICS
    target: Any = None  # the metric's target; None: its default (netapp_operator.autoscaling.SIGNALS)
    engine: Any = "hpa"  # one of AUTOSCALING_ENGINES: an HPA, or a KEDA ScaledObject
    prometheus_address: str | None = None  # where KEDA queries the netapps' metrics


@dataclasses.dataclass(frozen=True)
class Model:
    """Exactly one of `url` (fetched by an init container, checked against `sha256`) or a volume."""

    url: str | None = None
    sha256: str | None = None
    timeout_seconds: Any = MODEL_TIMEOUT_S
    volume_claim: str | None = None
    volume_path: str | None = None
    has_volume: bool = False


@dataclasses.dataclass(frozen=True)
class Access:
    """Who may use the netapp: with `require_token`, only robots presenting the token of its Secret. Default
    false, because unmodified 5G-ERA robots send no token; the token exists either way (made once)."""

    require_token: Any = False


@dataclasses.dataclass(frozen=True)
class TLS:
    secret_name: Any = None  # a kubernetes.io/tls Secret: the netapp serves HTTPS/WSS with it


@dataclasses.dataclass(frozen=True)
class State:
    """Where a stateful netapp keeps the session states robots save: a PVC, mounted writable as --state-dir."""

    volume_claim: str | None = None


@dataclasses.dataclass(frozen=True)
class EngineCache:
    """Where TensorRT keeps the engines it builds (minutes each on first start): a PVC (`claimName`), kept across
    pods, else an emptyDir of `size_limit` that lasts as long as the pod."""

    claim_name: Any = None
    size_limit: Any = ENGINE_CACHE_SIZE


STANDBY_NEXT_BEST = "nextBest"  # spec.standby.policy: the best eligible pool after the NetApp's own
MAX_STANDBY_REPLICAS = 4  # a standby is a warm copy waiting for robots, not capacity


@dataclasses.dataclass(frozen=True)
class Standby:
    """A warm copy on another pool, for robots that may move there: a pinned `pool`, or the next-best one."""

    pool: str | None = None
    policy: Any = STANDBY_NEXT_BEST
    replicas: Any = 1


@dataclasses.dataclass(frozen=True)
class Priority:
    """Robots' priority classes (docs/scaling.md#priorities): `robots`, the class of a robot without a class token
    and the highest it may claim (`netapp serve --robot-priority`); `token_sha256`, class -> the SHA-256 of the
    token that lets its robots claim that class (`--priority-token CLASS=HEX`); `weights`, class -> its weight when
    classes compete (`--priority-weights CLASS=WEIGHT,...`; a class left out keeps the netapp's default)."""

    robots: Any = DEFAULT_PRIORITY
    token_sha256: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    weights: Mapping[str, Any] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class NetAppSpec:
    image: Any
    port: Any = NETAPP_PORT
    replicas: Any = 1
    args: tuple[Any, ...] = ()
    env: tuple[Any, ...] = ()
    placement: Placement = Placement()
    resources: Resources = Resources()
    autoscaling: Autoscaling | None = None
    model: Model | None = None
    processor: Any = None  # `netapp serve --processor`: a built-in name or package.module:Class; None: the default
    access: Access = Access()
    tls: TLS | None = None
    state: State | None = None
    admission: Any = OPEN_ADMISSION  # `netapp serve --admission`: open, or measured (refuse past the hard limit)
    priority: Priority = Priority()
    standby: Standby | None = None
    # cameras the netapp pulls itself, [{name, url}] -> `netapp serve --source NAME=URL` (docs/cameras.md)
    sources: tuple[Any, ...] = ()
    rtp: RtpSpec | None = (
        None  # UDP ports robots push H.264 over RTP to -> `netapp serve --rtp-ports` (netapp_operator.rtp)
    )
    # STUN/TURN servers for WebRTC peers -> `netapp serve --ice-server`, TURN credentials from a Secret
    webrtc: WebRtcSpec | None = None
    publish: tuple[PublishSpec, ...] = ()  # brokers every result goes to (docs/broker.md)
    consume: tuple[PublishSpec, ...] = ()  # brokers whose work queue brings robots' frames (docs/broker.md)
    device: Any = AUTO_DEVICE  # `netapp serve --device`: one of netapp.protocol.DEVICES
    fp16: Any = False  # `netapp serve --fp16`: half precision where the device offers it (TensorRT)
    engine_cache: EngineCache | None = None  # `--trt-cache`: given, or an emptyDir when the device is tensorrt
    scaling: Scaling | None = None  # `idleToZero`: zero replicas after that long without a robot (netapp_operator.idle)
    problems: tuple[str, ...] = ()  # everything wrong, as sentences; empty when the spec can be deployed

    @property
    def requires_gpu(self) -> bool:
        """A netapp needs a GPU pool when it asks for one explicitly or requests GPUs."""
        return bool(self.placement.require_gpu) or self.gpus > 0

    @property
    def custom_processor(self) -> str | None:
        """The `package.module:Class` it serves instead of a built-in processor (it loads its own weights)."""
        return self.processor if isinstance(self.processor, str) and ":" in self.processor else None

    @property
    def gpus(self) -> int:
        """The GPUs each replica requests: `resources.gpus`, and at least one for a GPU device (cuda, tensorrt)."""
        asked = self.resources.gpus if isinstance(self.resources.gpus, int) else 0
        return max(asked, 1) if self.device in GPU_DEVICES else asked

    @property
    def trt_cache(self) -> EngineCache | None:
        """The engine cache to mount: the spec's, or an emptyDir one for the tensorrt device."""
        if self.engine_cache is None and self.device == TENSORRT_DEVICE:
            return EngineCache()
        return self.engine_cache


def _mapping(value: Any) -> Mapping[str, Any]:
    return value if isinstance(value, Mapping) else {}


def parse(raw: Mapping[str, Any] | None) -> NetAppSpec:
    """A NetApp's `spec` as the typed, frozen object every later step reads, with the CRD's defaults filled in."""
    raw = _mapping(raw)
    place = _mapping(raw.get("placement"))
    res = _mapping(raw.get("resources"))
    auto = raw.get("autoscaling")
    model = raw.get("model")
    volume = _mapping(model.get("volume")) if isinstance(model, Mapping) else {}
    tls = raw.get("tls")
    state = raw.get("state")
    standby = raw.get("standby")
    cache = raw.get("engineCache")
    spec = NetAppSpec(
        image=raw.get("image"),
        processor=raw.get("processor"),
        port=raw.get("port", NETAPP_PORT),
        replicas=raw.get("replicas", 1),
        args=tuple(raw.get("args") or ()),
        env=tuple(raw.get("env") or ()),
        sources=tuple(raw.get("sources") or ()),
        rtp=parse_rtp(raw.get("rtp")),
        webrtc=parse_webrtc(raw.get("webrtc")),
        publish=parse_publish(raw.get("publish")),
        consume=parse_publish(raw.get("consume")),
        placement=Placement(
            pool=place.get("pool") or None,
            policy=place.get("policy", "auto"),
            require_gpu=bool(place.get("requireGPU", False)),
        ),
        resources=Resources(
            cpu=None if res.get("cpu") is None else str(res["cpu"]),
            memory=None if res.get("memory") is None else str(res["memory"]),
            gpus=res.get("gpus", 0),
        ),
        autoscaling=None
        if auto is None
        else Autoscaling(
            max_replicas=_mapping(auto).get("maxReplicas"),
            min_replicas=_mapping(auto).get("minReplicas", 1),
            target_cpu_percent=_mapping(auto).get("targetCPUUtilizationPercentage", 70),
            metric=_mapping(auto).get("metric", "cpu"),
            target=_mapping(auto).get("target"),
            engine=_mapping(auto).get("engine", "hpa"),
            prometheus_address=_mapping(auto).get("prometheusAddress") or None,
        ),
        model=None
        if model is None
        else Model(
            url=_mapping(model).get("url"),
            sha256=None if _mapping(model).get("sha256") is None else str(model["sha256"]),
            timeout_seconds=_mapping(model).get("timeoutSeconds", MODEL_TIMEOUT_S),
            volume_claim=volume.get("claimName"),
            volume_path=volume.get("path"),
            has_volume=isinstance(model, Mapping) and "volume" in model,
        ),
        access=Access(require_token=_mapping(raw.get("access")).get("requireToken", False)),
        tls=None if tls is None else TLS(secret_name=_mapping(tls).get("secretName")),
        state=None if state is None else State(volume_claim=_mapping(_mapping(state).get("volume")).get("claimName")),
        admission=raw.get("admission", OPEN_ADMISSION),
        priority=Priority(
            robots=_mapping(raw.get("priority")).get("robots", DEFAULT_PRIORITY),
            token_sha256=dict(_mapping(_mapping(raw.get("priority")).get("tokenSha256"))),
            weights=dict(_mapping(_mapping(raw.get("priority")).get("weights"))),
        ),
        standby=None
        if standby is None
        else Standby(
            pool=_mapping(standby).get("pool") or None,
            policy=_mapping(standby).get("policy", STANDBY_NEXT_BEST),
            replicas=_mapping(standby).get("replicas", 1),
        ),
        device=raw.get("device", AUTO_DEVICE),
        fp16=raw.get("fp16", False),
        engine_cache=None
        if cache is None
        else EngineCache(
            claim_name=_mapping(cache).get("claimName"),
            size_limit=_mapping(cache).get("sizeLimit", ENGINE_CACHE_SIZE),
        ),
        scaling=parse_scaling(raw.get("scaling")),
    )
    return dataclasses.replace(spec, problems=tuple(_problems(spec)))


def _autoscaling_signal_problems(auto: Autoscaling) -> list[str]:
    found = []
    if auto.metric not in AUTOSCALING_METRICS:
        found.append(f"spec.autoscaling.metric must be one of {', '.join(AUTOSCALING_METRICS)}, got {auto.metric!r}")
    if auto.engine not in AUTOSCALING_ENGINES:
        found.append(f"spec.autoscaling.engine must be hpa or keda, got {auto.engine!r}")
    number = isinstance(auto.target, (int, float)) and not isinstance(auto.target, bool)
    if auto.target is not None and not (number and auto.target > 0):
        found.append(f"spec.autoscaling.target must be a number > 0, got {auto.target!r}")
    if auto.engine == "keda" and auto.metric != "cpu" and not auto.prometheus_address:
        found.append("spec.autoscaling.prometheusAddress is required with engine keda (KEDA queries Prometheus)")
    return found


def _problems(spec: NetAppSpec) -> list[str]:
    found: list[str] = []
    if not isinstance(spec.image, str) or not spec.image.strip():
        found.append("spec.image is required")
    port = spec.port
    if not isinstance(port, int) or isinstance(port, bool) or not 1 <= port <= 65535:
        found.append(f"spec.port must be an integer in 1..65535, got {port!r}")
    replicas = spec.replicas
    if not isinstance(replicas, int) or isinstance(replicas, bool) or replicas < 0:
        found.append(f"spec.replicas must be an integer >= 0, got {replicas!r}")
    auto = spec.autoscaling
    if auto is not None:
        lo, hi = auto.min_replicas, auto.max_replicas
        if not isinstance(hi, int) or hi < 1:
            found.append("spec.autoscaling.maxReplicas must be an integer >= 1")
        elif not isinstance(lo, int) or lo < 1 or lo > hi:
            found.append("spec.autoscaling.minReplicas must be an integer in 1..maxReplicas")
        target = auto.target_cpu_percent
        if not isinstance(target, int) or not 1 <= target <= 100:
            found.append("spec.autoscaling.targetCPUUtilizationPercentage must be in 1..100")
        found += _autoscaling_signal_problems(auto)
    processor = spec.processor
    if processor is not None and not (isinstance(processor, str) and PROCESSOR.match(processor)):
        found.append(f"spec.processor must be a built-in name or package.module:Class, got {processor!r}")
    model = spec.model
    if model is not None and spec.custom_processor:
        found.append("spec.model is for the built-in detector: a package.module:Class processor loads its own weights")
    if model is not None:
        if (model.url is not None) == model.has_volume:
            found.append("spec.model needs exactly one of url or volume")
        if model.sha256 is not None and not _SHA256.match(model.sha256):
            found.append("spec.model.sha256 must be 64 hexadecimal characters")
        if model.has_volume and not (model.volume_claim and model.volume_path):
            found.append("spec.model.volume needs claimName and path")
    if spec.state is not None and not (isinstance(spec.state.volume_claim, str) and spec.state.volume_claim):
        found.append("spec.state needs volume.claimName (a PersistentVolumeClaim for saved session states)")
    for key in ("cpu", "memory"):
        value = getattr(spec.resources, key)
        if value is not None and not _QUANTITY.match(value):
            found.append(f"spec.resources.{key} is not a Kubernetes quantity: {value!r}")
    gpus = spec.resources.gpus
    if not isinstance(gpus, int) or gpus < 0:
        found.append("spec.resources.gpus must be an integer >= 0")
    if spec.placement.policy not in ("edge", "cloud", "auto"):
        found.append(f"spec.placement.policy must be edge, cloud or auto, got {spec.placement.policy!r}")
    if not isinstance(spec.access.require_token, bool):
        found.append(f"spec.access.requireToken must be true or false, got {spec.access.require_token!r}")
    if spec.tls is not None and (not isinstance(spec.tls.secret_name, str) or not spec.tls.secret_name):
        found.append("spec.tls.secretName must name a kubernetes.io/tls Secret")
    if spec.admission not in ADMISSIONS:
        found.append(f"spec.admission must be one of {', '.join(ADMISSIONS)}, got {spec.admission!r}")
    if spec.priority.robots not in PRIORITY_CLASSES:
        found.append(f"spec.priority.robots must be one of {', '.join(PRIORITY_CLASSES)}, got {spec.priority.robots!r}")
    for name, digest in spec.priority.token_sha256.items():
        if name not in PRIORITY_CLASSES or not (isinstance(digest, str) and _SHA256.match(digest)):
            found.append(f"spec.priority.tokenSha256 maps a class ({', '.join(PRIORITY_CLASSES)}) to a SHA-256 in hex")
            break
    for name, weight in spec.priority.weights.items():
        number = isinstance(weight, (int, float)) and not isinstance(weight, bool)
        if name not in PRIORITY_CLASSES or not (number and math.isfinite(weight) and weight > 0):
            found.append(f"spec.priority.weights maps a class ({', '.join(PRIORITY_CLASSES)}) to a number above 0")
            break
    standby = spec.standby
    if standby is not None:
        if standby.policy != STANDBY_NEXT_BEST:
            found.append(f"spec.standby.policy must be {STANDBY_NEXT_BEST}, got {standby.policy!r}")
        count = standby.replicas
        if not isinstance(count, int) or isinstance(count, bool) or not 1 <= count <= MAX_STANDBY_REPLICAS:
            found.append(f"spec.standby.replicas must be an integer in 1..{MAX_STANDBY_REPLICAS}, got {count!r}")
    found += _device_problems(spec)
    for item in spec.env:
        if not isinstance(item, Mapping) or not item.get("name"):
            found.append("every spec.env entry needs a name")
            break
    found += _sources_problems(spec.sources)
    found += rtp_problems(spec.rtp, spec.replicas, spec.autoscaling is not None)
    found += webrtc_problems(spec.webrtc)
    found += scaling_problems(spec.scaling, spec.autoscaling is not None)
    found += publish_problems(spec.publish)
    found += publish_problems(spec.consume, CONSUME)
    return found


def source_args(sources: tuple[Any, ...]) -> list[str]:
    """`spec.sources` as `--source NAME=URL` pairs, as `netapp serve` takes them (checked by `_sources_problems`)."""
    return [arg for s in sources if isinstance(s, Mapping) for arg in ("--source", f"{s.get('name')}={s.get('url')}")]


def _sources_problems(sources: tuple[Any, ...]) -> list[str]:
    """What `netapp serve` would refuse in the cameras, said here so the NetApp's status shows it."""
    if not all(isinstance(s, Mapping) and s.get("name") and s.get("url") for s in sources):
        return ["every spec.sources entry needs a name and an rtsp:// url"]
    try:
        parse_sources(source_args(sources)[1::2])
    except ValueError as exc:
        return [f"spec.sources: {str(exc).replace('--source', 'source')}"]
    return []


def _device_problems(spec: NetAppSpec) -> list[str]:
    found = []
    if spec.device not in DEVICES:
        found.append(f"spec.device must be one of {', '.join(DEVICES)}, got {spec.device!r}")
    if not isinstance(spec.fp16, bool):
        found.append(f"spec.fp16 must be true or false, got {spec.fp16!r}")
    cache = spec.engine_cache
    if cache is not None:
        if spec.device not in (AUTO_DEVICE, TENSORRT_DEVICE):
            found.append(f"spec.engineCache is TensorRT's: set spec.device to tensorrt or auto, not {spec.device!r}")
        if cache.claim_name is not None and not (isinstance(cache.claim_name, str) and cache.claim_name):
            found.append("spec.engineCache.claimName must name a PersistentVolumeClaim")
        if not (isinstance(cache.size_limit, str) and _QUANTITY.match(cache.size_limit)):
            found.append(f"spec.engineCache.sizeLimit is not a Kubernetes quantity: {cache.size_limit!r}")
    return found
