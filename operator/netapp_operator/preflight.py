"""Before starting against Kubernetes: is a cluster configured here, and does its API answer at all?

Without this, a missing kubeconfig is a client library's traceback and an unreachable cluster makes kopf retry
forever; with it, each is one line that says what to do (exit code 2). Independent of the client library: it reads
the kubeconfig's current context and opens one TCP connection to the API server.
"""

from __future__ import annotations

import os
import socket
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import yaml


def kubeconfig_paths(kubeconfig: str | None = None) -> list[Path]:
    """The kubeconfig files a Kubernetes client would read: --kubeconfig, else $KUBECONFIG, else ~/.kube/config."""
    if kubeconfig:
        return [Path(kubeconfig).expanduser()]
    listed = [p for p in os.environ.get("KUBECONFIG", "").split(os.pathsep) if p]
    return [Path(p).expanduser() for p in listed] or [Path.home() / ".kube" / "config"]


def api_server(kubeconfig: str | None = None, flag: str | None = "--kubeconfig") -> tuple[str, str] | str:
    """(API server URL, where it came from), or a one-line problem saying what to do (`flag`: the command's
    option for a kubeconfig file, if it has one)."""
    if not kubeconfig and os.environ.get("KUBERNETES_SERVICE_HOST"):  # in a pod: its service account
        host, port = os.environ["KUBERNETES_SERVICE_HOST"], os.environ.get("KUBERNETES_SERVICE_PORT", "443")
        return f"https://{host}:{port}", "the pod's service account"
    paths = kubeconfig_paths(kubeconfig)
    existing = [p for p in paths if p.is_file()]
    if not existing:
        tried = " or ".join(str(p) for p in paths)
        how = f"set KUBECONFIG, pass {flag} or run in a cluster" if flag else "set KUBECONFIG or run in a cluster"
        return f"no Kubernetes cluster configured (no {tried}): {how}"
    try:
        config: Any = yaml.safe_load(existing[0].read_text()) or {}
        context_name = config.get("current-context")
        context = next(c["context"] for c in config.get("contexts", []) if c.get("name") == context_name)
        cluster = next(c["cluster"] for c in config.get("clusters", []) if c.get("name") == context["cluster"])
        return str(cluster["server"]), f"context {context_name!r} of {existing[0]}"
    except (OSError, yaml.YAMLError, AttributeError, KeyError, TypeError, StopIteration):
        return f"{existing[0]} has no usable current context: check it with kubectl config view"


def cluster_problem(
    kubeconfig: str | None = None, flag: str | None = "--kubeconfig", timeout_s: float = 5.0
) -> str | None:
    """Why this process cannot talk to a cluster, as one line; None when its API server accepts a connection."""
    found = api_server(kubeconfig, flag)
    if isinstance(found, str):
        return found
    server, origin = found
    url = urlparse(server)
    port = url.port or (443 if url.scheme == "https" else 80)
    try:
        with socket.create_connection((url.hostname or "", port), timeout=timeout_s):
            return None
    except OSError as exc:
        why = exc.strerror or type(exc).__name__
        return f"cannot reach the Kubernetes API at {server} ({origin}): {why}; is the cluster running?"
