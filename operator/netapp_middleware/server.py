"""Builds the middleware from command-line arguments and serves it with uvicorn."""

from __future__ import annotations

import argparse
import logging
import os
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from netapp_operator.constants import MIDDLEWARE_MANAGER, SERVICE_ACCOUNT_NAMESPACE_FILE

from netapp.tracing import TraceConfig, tracer_from_env

from .app import create_app
from .auth import RobotRegistry, TokenSigner, parse_robots, robot_priorities
from .backends import Backend
from .catalogue import DEFAULT_CATALOGUE, PLACEMENT_PATTERN, Catalogue, parse_catalogue
from .deployments import Registry
from .services import Services
from .sources import FileSource, KubeSource
from .switchover import Switchover, SwitchPolicy
from .switchover.ahead import AheadPolicy

if TYPE_CHECKING:
    from netapp_operator.kube import Kube

log = logging.getLogger(__name__)

GRACEFUL_SHUTDOWN_S = 5.0
SERVICE_NAME = "netapp-middleware"  # its traces' service.name unless OTEL_SERVICE_NAME says otherwise


def kube_client(kubeconfig: str | None) -> Kube:
    """The Kubernetes client, logging in on first use: in-cluster inside a pod, else the kubeconfig."""
    from netapp_operator.kube import Kube, environment_login

    return Kube(lambda: environment_login(kubeconfig), manager=MIDDLEWARE_MANAGER)


def default_namespace() -> str:
    try:
        return Path(SERVICE_ACCOUNT_NAMESPACE_FILE).read_text().strip() or "default"
    except OSError:
        return "default"


def _name_key(value: str, default_key: str) -> tuple[str, str]:
    name, _, key = value.partition(":")
    return name, key or default_key


def startup_problem(args: argparse.Namespace) -> str | None:
    """What would stop the middleware at start, as one line that says what to do; None when nothing."""
    try:
        TraceConfig.from_env(SERVICE_NAME)
    except ValueError as exc:  # a wrong OTEL_* variable
        return str(exc)
    files = (
        ("--robots-file", args.robots_file),
        ("--catalogue-file", args.catalogue_file),
        ("--operators-file", getattr(args, "operators_file", None)),
    )
    for option, path in files:
        if path and not Path(path).is_file():
            return f"{option} {path} does not exist: create it (see docs/middleware.md) or fix the path"
    if args.backend == "kubernetes" or args.robots_secret or args.catalogue_configmap:
        from netapp_operator.preflight import cluster_problem

        problem = cluster_problem(args.kubeconfig)
        if problem:
            return problem + (" (or use --backend local)" if args.backend == "kubernetes" else "")
    return None


def build_services(args: argparse.Namespace, *, kube: Kube | None = None) -> Services:
    """Everything the app needs, from the CLI arguments; the Kubernetes client is made only when used."""
    namespace = args.namespace or default_namespace()
    needs_kube = args.backend == "kubernetes" or args.robots_secret or args.catalogue_configmap
    if needs_kube and kube is None:
        kube = kube_client(args.kubeconfig)

    robots: Callable[[], dict[str, str]]
    priorities: Callable[[], dict[str, str]] = dict  # each robot's class, from the same document
    if args.robots_file:
        robots = FileSource(args.robots_file, parse_robots)
        priorities = FileSource(args.robots_file, robot_priorities)
        # Fail at start on a missing or malformed file, not at the first login.
        if not robots():
            log.warning("%s lists no robot: no robot can log in until one is added", args.robots_file)
        priorities()
    elif args.robots_secret:
        where = (kube, "Secret", namespace, *_name_key(args.robots_secret, "robots.yaml"))
        robots, priorities = KubeSource(*where, parse_robots), KubeSource(*where, robot_priorities)
    else:
        log.warning("no --robots-file or --robots-secret: no robot can log in")
        robots = dict

    catalogue: Callable[[], Catalogue]
    if args.catalogue_file:
        catalogue = FileSource(args.catalogue_file, parse_catalogue)
        catalogue()
    elif args.catalogue_configmap:
        catalogue = KubeSource(
            kube, "ConfigMap", namespace, *_name_key(args.catalogue_configmap, "catalogue.yaml"), parse_catalogue
        )
    else:
        default = parse_catalogue(DEFAULT_CATALOGUE)
        catalogue = lambda: default  # noqa: E731

    # A configured key must be a real one (an empty or short key is refused by TokenSigner); none at all draws a
    # random key per process, which signs every robot out at a restart: fine on a workstation, not in a cluster.
    key: bytes | None = None
    if args.token_key_file:
        key = Path(args.token_key_file).read_bytes().strip()
    elif "NETAPP_MIDDLEWARE_TOKEN_KEY" in os.environ:
        key = os.environ["NETAPP_MIDDLEWARE_TOKEN_KEY"].encode()
    else:
        log.warning("no --token-key-file or NETAPP_MIDDLEWARE_TOKEN_KEY: a random token key, lost at a restart")
    operators_file = getattr(args, "operators_file", None)
    backend: Backend
    if args.backend == "kubernetes":
        from .backends.kubernetes import KubernetesBackend

        backend = KubernetesBackend(namespace, kube)
    else:
        from .backends.local import LocalBackend

        backend = LocalBackend(model=args.model, ready_timeout_s=args.ready_timeout)
    signer = TokenSigner(key, ttl_s=args.token_ttl)
    registry = Registry(
        backend,
        max_per_robot=args.max_deployments_per_robot,
        max_netapps=args.max_netapps,
        token_for=signer.netapp_token,
    )
    placements = [p.strip() for p in args.switchover_placements.split(",") if p.strip()]
    for placement in placements:
        if not re.fullmatch(PLACEMENT_PATTERN, placement):
            raise ValueError(
                f"--switchover-placements: {placement!r} is no placement: give edge, cloud, auto or pool names"
            )
    policy = SwitchPolicy(
        sustain_s=args.switchover_sustain,
        warm_sustain_s=args.switchover_warm_sustain,
        min_dwell_s=args.switchover_dwell,
        trend_horizon_s=args.switchover_trend,
    )
    ahead = AheadPolicy(warm_lead_s=args.warm_lead, idle_grace_s=args.warm_idle_grace, min_dwell_s=args.route_dwell)
    return Services(
        registry=registry,
        robots=RobotRegistry(robots, priorities),
        signer=signer,
        catalogue=catalogue,
        era_token_ttl_s=args.era_token_ttl,
        kube=kube,
        operators=RobotRegistry(FileSource(operators_file, parse_robots) if operators_file else dict),
        switchover=Switchover(registry, catalogue, placements, policy, ready_timeout_s=args.ready_timeout, ahead=ahead),
        tracer=tracer_from_env(SERVICE_NAME),  # off unless OTEL_EXPORTER_OTLP_ENDPOINT is set (docs/tracing.md)
    )


def serve(args: argparse.Namespace) -> int:
    import uvicorn
    import yaml

    from netapp.serve_process import port_problem

    problem = startup_problem(args) or port_problem(args.host, args.port)
    if problem:
        print(f"netapp middleware: {problem}", file=sys.stderr)
        return 2
    try:
        app = create_app(build_services(args))
    except (ValueError, OSError, yaml.YAMLError) as exc:  # a configuration a person must fix: one line, no traceback
        log.error("%s", str(exc).replace("\n", " "))
        return 2
    log.info("middleware (%s backend) on http://%s:%d", args.backend, args.host, args.port)
    # Robots keep a long poll open all the time: without a bound, a graceful shutdown would wait for them all.
    uvicorn.run(
        app,
        host=args.host,
        port=args.port,
        log_level=args.log_level.lower(),
        access_log=False,
        timeout_graceful_shutdown=GRACEFUL_SHUTDOWN_S,
    )
    return 0
