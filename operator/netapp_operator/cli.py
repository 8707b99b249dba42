"""`netapp operator`: run the operator (argparse only at import; kopf loads when it runs)."""

from __future__ import annotations

import argparse
import ipaddress
import os
import sys

from netapp_operator.config import OperatorConfig
from netapp_operator.webrtc import default_webrtc

ROLLOUT_TOKEN_ENV = "NETAPP_OPERATOR_ROLLOUT_TOKEN"
DEFAULTS = OperatorConfig()  # the flags' defaults are the config's, never a second copy


def add_arguments(parser: argparse.ArgumentParser) -> None:
    env_ns = [n for n in os.environ.get("NETAPP_NAMESPACES", "").replace(",", " ").split() if n]
    scope = parser.add_mutually_exclusive_group()
    scope.add_argument(
        "-n",
        "--namespace",
        action="append",
        dest="namespaces",
        default=None,
        metavar="NS",
        help="watch NetApps in this namespace (repeatable; env NETAPP_NAMESPACES); default: all",
    )
    scope.add_argument("-A", "--all-namespaces", action="store_true", help="watch NetApps in all namespaces")
    parser.set_defaults(env_namespaces=env_ns)
    # 8081: the middleware listens on 8080 by default, and both may run on one workstation.
    parser.add_argument(
        "--liveness",
        default=os.environ.get("NETAPP_LIVENESS", "http://0.0.0.0:8081/healthz"),
        help="kopf liveness endpoint (default %(default)s; empty to disable)",
    )
    parser.add_argument(
        "--metrics",
        default=os.environ.get("NETAPP_OPERATOR_METRICS", ""),
        metavar="URL",
        help="serve Prometheus metrics here, e.g. http://0.0.0.0:8082/metrics (the chart does; default: off)",
    )
    parser.add_argument(
        "--failover-grace",
        type=float,
        default=DEFAULTS.failover_grace_seconds,
        metavar="SECONDS",
        help="how long a pool may have no ready nodes before its NetApps move (default %(default)s)",
    )
    parser.add_argument(
        "--check-interval",
        type=float,
        default=DEFAULTS.check_interval_seconds,
        metavar="SECONDS",
        help="how often placement and pool health are re-checked (default %(default)s)",
    )
    parser.add_argument(
        "--model-init-image",
        default=DEFAULTS.model_init_image,
        help="image of the model download init container (needs sh, curl, sha256sum)",
    )
    parser.add_argument(
        "--model-cache-dir",
        default=DEFAULTS.model_cache_dir,
        help="each node's cache of fetched models, by sha256 (a hostPath; default %(default)s; '' for none)",
    )
    parser.add_argument(
        "--default-model-url",
        default=DEFAULTS.default_model_url,
        help="model for NetApps without spec.model (default YOLOX-Nano; empty: none)",
    )
    parser.add_argument(
        "--default-model-sha256",
        default=DEFAULTS.default_model_sha256,
        help="sha256 of the default model (empty: not checked)",
    )
    parser.add_argument(
        "--run-as-user", type=int, default=DEFAULTS.run_as_user, help="uid of netapp pods (default %(default)s)"
    )
    parser.add_argument(
        "--watch-server-timeout",
        type=int,
        default=DEFAULTS.watch_server_timeout,
        metavar="SECONDS",
        help="server-side timeout of each watch request (default %(default)s)",
    )
    parser.add_argument(
        "--watch-client-timeout",
        type=int,
        default=DEFAULTS.watch_client_timeout,
        metavar="SECONDS",
        help="client-side timeout of each watch request (default %(default)s)",
    )

    parser.add_argument(
        "--rollout-poll",
        type=float,
        default=DEFAULTS.rollout_poll_seconds,
        metavar="SECONDS",
        help="how often a NetApp's running model rollout is read from its pod (default %(default)s)",
    )
    parser.add_argument(
        "--waker-ip",
        default=os.environ.get("POD_IP", ""),
        metavar="IP",
        help="the operator pod's IP: sleeping NetApps' Services send robots there to be told to wait while their "
        "NetApp wakes (docs/kubernetes.md#scale-to-zero; default $POD_IP, the chart sets it; empty: no waker)",
    )
    parser.add_argument(
        "--waker-port",
        type=int,
        default=DEFAULTS.waker_port,
        metavar="PORT",
        help="the waker's port (default %(default)s)",
    )
    parser.add_argument(
        "--ice-server",
        action="append",
        default=[],
        metavar="URL",
        help="STUN/TURN server of NetApps without spec.webrtc (repeatable; docs/cameras.md#webrtc); default: none",
    )
    parser.add_argument(
        "--turn-secret",
        default="",
        metavar="NAME",
        help="Secret (keys username, credential) of the TURN server, in each NetApp's own namespace",
    )


def rollout_token() -> str:
    """The token the operator starts model rollouts with, from $NETAPP_OPERATOR_ROLLOUT_TOKEN (the chart puts a
    Secret's there); empty: no rollouts, a changed model restarts the pods (docs/rollouts.md#kubernetes)."""
    return os.environ.get(ROLLOUT_TOKEN_ENV, "").strip()


def config_from_args(args: argparse.Namespace) -> OperatorConfig:
    """Raises ValueError (one line) for a wrong --ice-server or --turn-secret."""
    if not 0 < args.waker_port < 65536:
        raise ValueError(f"--waker-port must be a port number (1 to 65535), got {args.waker_port}")
    namespaces: tuple[str, ...] = ()
    if not args.all_namespaces:
        namespaces = tuple(args.namespaces or args.env_namespaces or ())
    return OperatorConfig(
        namespaces=namespaces,
        failover_grace_seconds=args.failover_grace,
        check_interval_seconds=args.check_interval,
        model_init_image=args.model_init_image,
        model_cache_dir=args.model_cache_dir,
        default_model_url=args.default_model_url,
        default_model_sha256=args.default_model_sha256,
        liveness_endpoint=args.liveness or None,
        metrics_endpoint=args.metrics or None,
        watch_server_timeout=args.watch_server_timeout,
        watch_client_timeout=args.watch_client_timeout,
        run_as_user=args.run_as_user,
        rollout_token=rollout_token(),
        rollout_poll_seconds=args.rollout_poll,
        default_webrtc=default_webrtc(args.ice_server, args.turn_secret),
        waker_ip=waker_ip(args.waker_ip),
        waker_port=args.waker_port,
    )


def waker_ip(text: str) -> str:
    """--waker-ip as written into EndpointSlices: an IP address (ValueError, one line, when not)."""
    if not text.strip():
        return ""
    try:
        return str(ipaddress.ip_address(text.strip()))
    except ValueError:
        raise ValueError(f"--waker-ip must be the operator pod's IP address (env POD_IP), got {text!r}") from None


def run(args: argparse.Namespace) -> int:
    import asyncio

    import kopf

    from netapp.tracing import TraceConfig
    from netapp_operator.handlers import register
    from netapp_operator.preflight import cluster_problem
    from netapp_operator.tracing import SERVICE_NAME

    try:
        TraceConfig.from_env(SERVICE_NAME)  # a wrong OTEL_* variable: say which, not a traceback at startup
        config = config_from_args(args)
        problem = cluster_problem(flag=None)  # kopf reads $KUBECONFIG or the pod's service account
    except ValueError as exc:
        problem = str(exc)
    if problem:  # kopf would retry forever
        print(f"netapp operator: {problem}", file=sys.stderr)
        return 2
    registry = kopf.OperatorRegistry()
    register(registry, config)
    # Standalone: one replica (the Deployment uses the Recreate strategy), so no peering CRDs are needed.
    asyncio.run(
        kopf.operator(
            registry=registry,
            clusterwide=config.clusterwide,
            namespaces=list(config.namespaces),
            standalone=True,
            liveness_endpoint=config.liveness_endpoint,
        )
    )
    return 0
