"""`netapp middleware`: run the robot-facing middleware API; `netapp middleware hash-secret` hashes a robot secret.

Light on purpose (argparse only): the implementation is imported when the command runs.
"""

from __future__ import annotations

import argparse
import os
import sys


def _default_host() -> str:
    # In a pod the Service must reach us; on a workstation, stay on loopback.
    return os.environ.get("NETAPP_MIDDLEWARE_HOST") or (
        "0.0.0.0" if os.environ.get("KUBERNETES_SERVICE_HOST") else "127.0.0.1"
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--host",
        default=_default_host(),
        help="listen address (default 127.0.0.1; 0.0.0.0 inside a pod; env NETAPP_MIDDLEWARE_HOST)",
    )
    parser.add_argument("--port", type=int, default=8080, help="listen port (default 8080)")
    parser.add_argument(
        "--backend",
        choices=("local", "kubernetes"),
        default="local",
        help="local: netapp processes on this machine (default); kubernetes: NetApp resources",
    )
    robots = parser.add_mutually_exclusive_group()
    robots.add_argument("--robots-file", help="YAML map robot id -> scrypt hash (see `hash-secret`)")
    parser.add_argument(
        "--operators-file",
        help="YAML map operator name -> scrypt hash: who may log in to /dashboard (separate from the robots)",
    )
    robots.add_argument(
        "--robots-secret",
        metavar="NAME[:KEY]",
        help="read the robots YAML from a Kubernetes Secret key (default key robots.yaml)",
    )
    catalogue = parser.add_mutually_exclusive_group()
    catalogue.add_argument("--catalogue-file", help="YAML catalogue of apps (default: the built-in one)")
    catalogue.add_argument(
        "--catalogue-configmap",
        metavar="NAME[:KEY]",
        help="read the catalogue from a ConfigMap key (default key catalogue.yaml)",
    )
    parser.add_argument(
        "--token-key-file",
        help="HMAC key for tokens, at least 32 bytes; a stable one keeps tokens valid across restarts (default: env "
        "NETAPP_MIDDLEWARE_TOKEN_KEY, else a random key per process)",
    )
    parser.add_argument("--token-ttl", type=float, default=3600.0, help="token lifetime in seconds (default 3600)")
    parser.add_argument(
        "--era-token-ttl",
        type=float,
        default=24 * 3600.0,
        help="lifetime of 5G-ERA /Login tokens, which era-5g-client never refreshes (default 86400)",
    )
    parser.add_argument(
        "--max-deployments-per-robot",
        type=int,
        default=16,
        metavar="N",
        help="deployments one robot may hold at once (default 16)",
    )
    parser.add_argument(
        "--max-netapps",
        type=int,
        default=64,
        metavar="N",
        help="NetApps the middleware runs at once, for all robots together (default 64)",
    )
    switch = parser.add_argument_group("switchover (a robot over its latency budget moves to a better placement)")
    switch.add_argument(
        "--switchover-placements",
        default="edge,cloud",
        metavar="P1,P2,...",
        help="placements a robot may be moved between, in order of preference (default edge,cloud; one: off)",
    )
    ahead = parser.add_argument_group("deploy ahead (robots' routes, warm standbys of catalogue apps)")
    for group, flag, default, what in (
        (switch, "--switchover-sustain", 2.0, "seconds a robot's p95 must stay over its budget before a move"),
        (
            switch,
            "--switchover-warm-sustain",
            0.0,
            "... before a move into a netapp already Ready there (a standby: hedged, it costs nothing)",
        ),
        (switch, "--switchover-dwell", 20.0, "seconds a robot stays on a placement at least, so that it does not flap"),
        (
            switch,
            "--switchover-trend",
            2.0,
            "move early when a rising p95 trend crosses the budget within S s (0: off)",
        ),
        (ahead, "--warm-lead", 60.0, "seconds before a robot's eta its route's pool is readied"),
        (ahead, "--warm-idle-grace", 30.0, "seconds a warm netapp (standby or route) no robot needs waits to go"),
        (ahead, "--route-dwell", 5.0, "seconds at least between a route's waypoints, and between moves on it"),
    ):
        group.add_argument(flag, type=float, default=default, metavar="S", help=f"{what} (default {default:g})")
    kube = parser.add_argument_group("kubernetes backend")
    kube.add_argument("--namespace", help="namespace of the NetApps (default: the pod's own, else default)")
    kube.add_argument("--kubeconfig", help="kubeconfig file (default: in-cluster config, else $KUBECONFIG)")
    local = parser.add_argument_group("local backend")
    local.add_argument("--model", help="model path or URL for every local netapp, instead of the spec's model URL")
    local.add_argument(
        "--ready-timeout",
        type=float,
        default=180.0,
        help="seconds a local netapp may take to become ready (default 180)",
    )
    sub = parser.add_subparsers(dest="middleware_command", metavar="{hash-secret,demo}")
    hasher = sub.add_parser("hash-secret", help="print the scrypt hash of a robot secret for the robots file")
    hasher.add_argument("secret", nargs="?", help="the secret (default: read one line from stdin)")
    from . import demo  # argparse only at import, like this module

    demo.add_arguments(
        sub.add_parser("demo", help="the whole robot flow locally: middleware, deploy, stream, results, delete")
    )


def run(args: argparse.Namespace) -> int:
    if args.middleware_command == "hash-secret":
        from .auth import hash_secret

        secret = args.secret if args.secret is not None else sys.stdin.readline().rstrip("\n")
        if not secret:
            print("hash-secret: empty secret", file=sys.stderr)
            return 2
        print(hash_secret(secret))
        return 0
    if args.middleware_command == "demo":
        from . import demo

        return demo.run(args)
    from .server import serve

    return serve(args)
