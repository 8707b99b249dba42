"""`netapp serve`: serve detection with an ONNX model, another built-in processor, or your own."""

from __future__ import annotations

import argparse
import logging
import os
import ssl
from pathlib import Path

from netapp.models.detector import DetectorConfig
from netapp.models.options import add_model_arguments
from netapp.protocol import (
    ADMISSIONS,
    ADVERTISE_URL_ENV,
    CLUSTER_KEY_ENV,
    DEFAULT_PORT,
    DEFAULT_PRIORITY,
    NETAPP_NAME_ENV,
    PEER_CA_ENV,
    PRIORITY_CLASSES,
    PRIORITY_TOKENS_ENV,
    PRIORITY_WEIGHTS_ENV,
    TOKEN_DIGEST_ENV,
    TOKEN_ENV,
    parse_priority,
)
from netapp.sdk.processor import Processor
from netapp.server.brokers.args import add_broker_arguments, consume_addresses, publish_addresses
from netapp.server.cluster.ownership import Cluster
from netapp.server.pipeline.priorities import parse_weights
from netapp.server.rollout.options import add_rollout_arguments, rollout_settings
from netapp.server.rtp.ports import parse_port_range
from netapp.server.settings import DEFAULT_WEIGHTS, Settings
from netapp.server.sources.naming import parse_sources
from netapp.startup import collector_paused
from netapp.webrtc_ice import ice_addresses_for, parse_ice_server

log = logging.getLogger("netapp.serve")


# Settings that bound what any client can make the netapp hold, as flags: (flag, Settings field, type, help).
LIMIT_FLAGS = (
    ("--max-sessions", "max_sessions", int, "open sessions"),
    ("--max-waiting", "max_waiting", int, "?wait=true requests waiting at once"),
    ("--max-connections", "max_connections", int, "open connections and requests"),
    ("--head-timeout", "head_timeout_s", float, "seconds a connection has to send a request head"),
    ("--body-timeout", "body_timeout_s", float, "seconds a request body has to arrive"),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from netapp.builtin_processors import BUILTIN, DEFAULT

    settings = Settings()
    detector = DetectorConfig(model_path="")
    parser.add_argument(
        "--processor",
        metavar="NAME|MODULE:CLASS",
        help=f"what to serve: a built-in name ({', '.join(sorted(BUILTIN))}; default {DEFAULT}; object-tracking adds a"
        " track_id to each detection) or package.module:Class (a netapp.sdk Processor subclass made with no arguments)",
    )
    parser.add_argument(
        "--model", help="ONNX model of a built-in processor: a path, or an http(s) URL (optionally #sha256=HEX)"
    )
    parser.add_argument("--sha256", help="expected sha256 of the model file")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0 in a container)")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT}, as 5G-ERA)")
    add_model_arguments(parser)  # --labels --task --layout --conf --iou --max-detections --mask-format --device ...
    parser.add_argument(
        "--max-payload",
        type=int,
        default=settings.max_payload_bytes,
        help="largest frame in bytes (default %(default)s)",
    )
    parser.add_argument(
        "--max-pixels",
        type=int,
        default=settings.max_pixels,
        help="largest picture in pixels, read from its header before decoding (default %(default)s: 4K and a bit)",
    )
    parser.add_argument(
        "--queue-size",
        type=int,
        default=settings.queue_size,
        help="frames waiting per robot; newest wins (default %(default)s)",
    )
    parser.add_argument(
        "--max-batch",
        type=int,
        default=settings.max_batch,
        help="frames per inference across robots (default %(default)s: what the model allows)",
    )
    parser.add_argument(
        "--threads",
        type=int,
        default=detector.threads,
        help="onnxruntime intra-op threads (default %(default)s: all cores)",
    )
    parser.add_argument(
        "--spin-wait",
        action="store_true",
        default=detector.spin_wait,
        help="onnxruntime threads spin between operators (faster alone on a machine, slower beside other work)",
    )
    parser.add_argument(
        "--lanes",
        type=at_least_one,
        default=None,
        help="batches processed at once by a stateless processor (default: 2 on 2 cores or more, else 1)",
    )
    parser.add_argument(
        "--prepare-threads",
        type=int,
        default=None,
        help="decode threads beside inference (default: 0 on 2 cores or fewer, else 2)",
    )
    parser.add_argument(
        "--opencv-threads",
        type=at_least_one,
        default=settings.opencv_threads,
        help="OpenCV's threads for one picture's decoding and resizing (default %(default)s: the lanes already run "
        "side by side)",
    )
    parser.add_argument(
        "--hard-share",
        type=float,
        default=settings.hard_share,
        help="the published hard limit leaves each robot this share of its input rate, by the measured capacity; with "
        "--admission measured a robot past it is refused (default %(default)s; 0: no hard limit)",
    )
    parser.add_argument(
        "--admission",
        choices=ADMISSIONS,
        default=settings.admission,
        help="open: robots up to --max-sessions share the capacity; measured: also refuse a robot past the measured "
        "hard limit, for deployments where something else places it (default %(default)s; docs/scaling.md#admission)",
    )
    parser.add_argument(
        "--middleware-address",
        default=os.environ.get("MIDDLEWARE_ADDRESS"),
        help="POST the 5G-ERA heartbeat (robots served, optimal and hard limits) to ADDRESS/status/netapp every "
        "second (default: $MIDDLEWARE_ADDRESS; NETAPP_ID and NETAPP_NAME name this netapp)",
    )
    parser.add_argument(
        "--state-dir", help="directory (a volume) where SAVE_STATE / LOAD_STATE keep stateful sessions' states"
    )
    parser.add_argument("--download-timeout", type=float, default=60.0, help="model download timeout, seconds")
    parser.add_argument(
        "--token-sha256",
        default=os.environ.get(TOKEN_DIGEST_ENV) or None,
        metavar="HEX",
        help="robots must send the bearer token with this SHA-256 (env NETAPP_TOKEN_SHA256; default: none needed)",
    )
    parser.add_argument(
        "--token-file",
        help=f"robots must send the bearer token in this file (or ${TOKEN_ENV}: the token itself; default: none)",
    )
    parser.add_argument(
        "--robot-priority",
        choices=PRIORITY_CLASSES,
        default=DEFAULT_PRIORITY,
        help="the priority class of a robot without a class token, and the highest it may claim (default %(default)s;"
        " docs/scaling.md#priorities)",
    )
    parser.add_argument(
        "--priority-token",
        action="append",
        default=[t for t in os.environ.get(PRIORITY_TOKENS_ENV, "").split(",") if t.strip()],
        metavar="CLASS=HEX",
        help="a robot bearing the token with this SHA-256 may claim up to CLASS (and is let in as with the netapp's "
        f"token); repeat for more tokens (default: ${PRIORITY_TOKENS_ENV}, comma-separated)",
    )
    parser.add_argument(
        "--priority-weights",
        default=os.environ.get(PRIORITY_WEIGHTS_ENV, ""),
        metavar="low=1,normal=2,high=4",
        help="each class's weight when classes compete for the netapp's time; a class left out keeps its default "
        f"(default: ${PRIORITY_WEIGHTS_ENV}, else low=1,normal=2,high=4; docs/scaling.md#priorities)",
    )
    parser.add_argument(
        "--no-next-turn-hint",
        dest="next_turn_hint",
        action="store_false",
        help="results carry no next-turn hint: robots pace on their frames' waits, as before it (for comparisons)",
    )
    parser.add_argument("--tls-cert", help="serve HTTPS and WSS only, with this PEM certificate (needs --tls-key)")
    parser.add_argument("--tls-key", help="the PEM private key of --tls-cert")
    limits = parser.add_argument_group("limits (docs/security.md#limits)")
    for flag, field, kind, text in LIMIT_FLAGS:
        limits.add_argument(flag, dest=field, type=kind, default=getattr(settings, field), help=f"{text} (%(default)s)")
    parser.add_argument(
        "--advertise-url",
        default=os.environ.get(ADVERTISE_URL_ENV),
        help=f"how the other replicas reach this one, http://POD_IP:PORT, or https:// with --tls-cert (env "
        f"{ADVERTISE_URL_ENV})",
    )
    parser.add_argument(
        "--peer-ca",
        default=os.environ.get(PEER_CA_ENV) or None,
        metavar="CA.pem",
        help="verify the other replicas' certificates against this CA bundle when they advertise https:// (env "
        f"{PEER_CA_ENV}; default: this replica's own --tls-cert; docs/security.md#tls-between-replicas)",
    )
    parser.add_argument(
        "--cluster-key-file",
        help=f"file holding the key the replicas share (a Secret; or env {CLUSTER_KEY_ENV}); without: one replica",
    )
    parser.add_argument(
        "--source",
        action="append",
        default=[],
        metavar="NAME=rtsp://HOST/PATH",
        help="a camera the netapp pulls itself, its results to `netapp watch URL --source NAME`; repeat for more; "
        "#transport=udp|tcp after the URL picks its transport (default: UDP, else TCP; docs/cameras.md)",
    )
    parser.add_argument(
        "--source-results",
        metavar="DIR",
        help="write each camera's results as JSON lines to DIR/NAME.jsonl, rotated at --source-results-mb (3 old "
        "files kept; docs/cameras.md#results)",
    )
    parser.add_argument(
        "--source-results-mb",
        type=float,
        default=settings.source_results_bytes / 2**20,
        help="size at which a --source-results file is rotated, MiB (default %(default)g)",
    )
    add_rollout_arguments(parser)
    add_broker_arguments(parser)
    parser.add_argument(
        "--rtp-ports",
        metavar="FIRST-LAST",
        help="UDP ports for robots that send H.264 over RTP (INIT with rtp; one port per session, at most 1024), "
        "e.g. 50000-50099; default: no RTP (docs/cameras.md#rtp-push)",
    )
    parser.add_argument(
        "--ice-server",
        action="append",
        default=[],
        metavar="URL",
        help="a STUN or TURN server for WebRTC peers (stun:HOST:PORT, turn:HOST:PORT), repeatable; a TURN server's "
        "credentials come from $NETAPP_ICE_USERNAME and $NETAPP_ICE_CREDENTIAL (or _FILE); default: none is "
        "contacted (docs/cameras.md#webrtc)",
    )
    parser.add_argument(
        "--webrtc-peers",
        type=int,
        default=settings.webrtc_max_peers,
        help="WebRTC peer connections held at most (POST /webrtc/offer; default %(default)s)",
    )
    parser.add_argument(
        "--camera-leases",
        metavar="NAMESPACE",
        default=os.environ.get("NETAPP_CAMERA_LEASES") or None,
        help="with several replicas: each --source camera is pulled by the one replica holding its Lease in NAMESPACE "
        "(the pod's service account or $KUBECONFIG, and RBAC for leases; a WATCH at another replica is relayed "
        "from the holder; env NETAPP_CAMERA_LEASES; docs/cameras.md#several-replicas)",
    )
    parser.add_argument(
        "--drain-grace",
        type=float,
        default=settings.drain_grace_s,
        help="after SIGTERM, longest wait for the robots to move, seconds (default %(default)s)",
    )


def admin_digest() -> str | None:
    """The digest of the token that may start a rollout over HTTP, from the environment (docs/rollouts.md)."""
    from netapp.protocol import ADMIN_TOKEN_DIGEST_ENV
    from netapp.server.access import check_digest

    value = os.environ.get(ADMIN_TOKEN_DIGEST_ENV, "").strip()
    return check_digest(value) if value else None


def cluster_key(path: str | None) -> bytes | None:
    """The replicas' shared key: from the file, else the environment, else none (one replica on its own)."""
    if path:
        try:
            key = Path(path).read_bytes().strip()
        except OSError as exc:
            raise ValueError(f"cannot read --cluster-key-file: {exc}") from exc
        if not key:
            raise ValueError(f"--cluster-key-file {path} is empty: put 32 random bytes in it (openssl rand -hex 32)")
        return key
    return os.environ.get(CLUSTER_KEY_ENV, "").strip().encode() or None


def token_sha256(args: argparse.Namespace) -> str | None:
    """The digest of the token robots must send, from exactly one of --token-sha256 (or $NETAPP_TOKEN_SHA256),
    --token-file or $NETAPP_TOKEN; None: the netapp is open. ValueError saying what is wrong."""
    from netapp.server.access import check_digest, token_digest

    token = os.environ.get(TOKEN_ENV, "").strip() or None
    if args.token_file:
        try:
            token = Path(args.token_file).read_text().strip()
        except OSError as exc:
            raise ValueError(f"cannot read --token-file: {exc}") from exc
        if not token:
            raise ValueError(f"--token-file {args.token_file} is empty: put the token in it, or leave the option out")
    if token and args.token_sha256:
        raise ValueError(f"give the token (--token-file or ${TOKEN_ENV}) or its digest (--token-sha256), not both")
    return token_digest(token) if token else check_digest(args.token_sha256) if args.token_sha256 else None


def priority_tokens(values: list[str]) -> dict[str, int]:
    """`--priority-token CLASS=HEX` values -> {digest: class}; ValueError saying what is wrong."""
    from netapp.server.access import check_digest

    tokens: dict[str, int] = {}
    for value in values:
        name, sep, digest = value.partition("=")
        if not sep:
            raise ValueError(
                f"--priority-token takes CLASS=SHA256 (e.g. high=$(printf %s TOKEN | sha256sum)), got {value!r}"
            )
        tokens[check_digest(digest)] = parse_priority(name.strip())
    return tokens


def check_tls(cert: str | None, key: str | None) -> None:
    """Load the certificate and key once at start, so that a wrong path or a key that does not match is one clear
    line (ValueError), not a traceback from inside uvicorn."""
    if bool(cert) != bool(key):
        raise ValueError("--tls-cert and --tls-key go together: give both, or neither for plain HTTP")
    if cert:
        try:
            ssl.create_default_context(ssl.Purpose.CLIENT_AUTH).load_cert_chain(cert, key)
        except (OSError, ssl.SSLError) as exc:
            raise ValueError(f"cannot use --tls-cert {cert} with --tls-key {key}: {exc}") from exc


def peer_ca(args: argparse.Namespace, clustered: bool) -> str | None:
    """The CA bundle other replicas are verified against (--peer-ca, else a TLS replica's own --tls-cert), checked
    at start: ValueError, one line, for a replica whose advertised scheme is not the one it serves (the others could
    not reach it), or a CA file that holds no certificate."""
    from netapp.server.cluster.peer_tls import peer_context

    https = clustered and (args.advertise_url or "").lower().startswith("https://")
    if clustered and args.tls_cert and not https:
        raise ValueError("this replica serves HTTPS (--tls-cert): advertise it as --advertise-url https://POD_IP:PORT")
    if https and not args.tls_cert:
        raise ValueError("--advertise-url https:// is for a replica that serves HTTPS: give --tls-cert and --tls-key")
    ca = args.peer_ca or (args.tls_cert if https else None)
    if ca:
        try:
            peer_context(ca)
        except (OSError, ssl.SSLError) as exc:
            raise ValueError(f"cannot verify other replicas with --peer-ca {ca}: {exc}") from exc
    return ca


def at_least_one(text: str) -> int:
    """An argparse type: an integer of 1 or more (argparse prints the message and exits 2 otherwise)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of 1 or more")
    return value


def run(args: argparse.Namespace) -> int:
    with collector_paused():  # the server's imports and the model's load and first run (netapp.startup)
        prepared = prepare(args)
    if isinstance(prepared, int):
        return prepared
    from netapp.server.runner import serve

    processor, settings = prepared
    serve(
        processor,
        args.host,
        args.port,
        settings,
        log_level=args.log_level.lower(),
        tls_cert=args.tls_cert,
        tls_key=args.tls_key,
    )
    return 0


def prepare(args: argparse.Namespace) -> tuple[Processor, Settings] | int:
    """The processor, loaded and run once, and the settings to serve it with; an exit code after a one-line error
    when the command line or the model is wrong."""
    from netapp.models.source import ModelUnavailable
    from netapp.serve_process import port_problem
    from netapp.server.processor_loading import ProcessorUnavailable, build_processor
    from netapp.server.runner import serve  # noqa: F401  (imported here, with the collector paused)
    from netapp.server.services import SERVICE_NAME
    from netapp.tracing import tracer_from_env

    problem = port_problem(args.host, args.port)
    if problem:  # before the model loads, so the answer comes at once
        log.error("%s", problem)
        return 2
    try:
        key = cluster_key(args.cluster_key_file)
        Cluster.build(key, args.advertise_url)  # a bad key or address: say so before loading anything
        check_tls(args.tls_cert, args.tls_key)
        peers_ca = peer_ca(args, clustered=key is not None)
        digest = token_sha256(args)
        class_tokens = priority_tokens(args.priority_token)
        weights = parse_weights(args.priority_weights) if args.priority_weights.strip() else DEFAULT_WEIGHTS
        tracer_from_env(SERVICE_NAME)  # a wrong OTEL_* variable: say which before loading anything
        sources = parse_sources(args.source)
        rtp_ports = parse_port_range(args.rtp_ports) if args.rtp_ports else None
        ice_servers = tuple(parse_ice_server(url) for url in args.ice_server)
        if not 0.01 <= args.source_results_mb <= 2**20:
            raise ValueError(f"--source-results-mb must be between 0.01 and 1048576, got {args.source_results_mb:g}")
        publish = publish_addresses(args.publish, os.environ.get("NETAPP_ID"))
        consume = consume_addresses(args.consume, os.environ.get("NETAPP_ID"))
        processor = build_processor(args)
    except (ProcessorUnavailable, ModelUnavailable, ValueError, OSError) as exc:
        log.error("%s", exc)
        return 2
    settings = Settings(
        max_payload_bytes=args.max_payload,
        max_pixels=args.max_pixels,
        queue_size=args.queue_size,
        max_batch=args.max_batch,
        cluster_key=key,
        advertise_url=args.advertise_url,
        peer_ca=peers_ca,
        drain_grace_s=args.drain_grace,
        hard_share=args.hard_share,
        admission=args.admission,
        middleware_address=args.middleware_address or None,
        netapp_id=os.environ.get("NETAPP_ID"),
        netapp_name=os.environ.get(NETAPP_NAME_ENV),
        state_dir=args.state_dir,
        sources=sources,
        rtp_ports=rtp_ports,
        rtp_host=args.host,
        camera_leases=args.camera_leases,
        webrtc_ice_servers=ice_servers,
        webrtc_addresses=ice_addresses_for(args.host),
        webrtc_max_peers=args.webrtc_peers,
        source_results=args.source_results,
        source_results_bytes=int(args.source_results_mb * 2**20),
        publish=publish,
        consume=consume,
        **{field: getattr(args, field) for _, field, _, _ in LIMIT_FLAGS},
    )
    settings.token_sha256 = digest
    settings.priority_tokens = class_tokens
    settings.next_turn_hint = args.next_turn_hint
    settings.robot_priority = parse_priority(args.robot_priority)
    settings.priority_weights = weights
    if args.prepare_threads is not None:
        settings.prepare_threads = args.prepare_threads
    if args.lanes is not None:
        settings.lanes = args.lanes
    settings.opencv_threads = args.opencv_threads
    try:
        rollout_settings(args, settings)
        settings.admin_token_sha256 = admin_digest()
    except ValueError as exc:
        log.error("%s", exc)
        return 2
    described = " ".join(str(v) for k, v in processor.describe().items() if k in ("name", "platform", "provider"))
    log.info(
        "serving %s on %s://%s:%d (%s)",
        described,
        "https" if args.tls_cert else "http",
        args.host,
        args.port,
        "robots need the token" if digest else "open to any robot",
    )
    return processor, settings
