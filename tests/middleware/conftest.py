"""Fixtures for the middleware tests: a kmock Kubernetes API and the middleware on real loopback ports.

Both run in threads with their own event loops, so that tests stay synchronous and can use the robot-side
clients (requests, era-5g-client) exactly as a robot would.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from netapp_middleware.auth import RobotRegistry, TokenSigner, hash_secret, parse_robots
from netapp_middleware.backends import Backend
from netapp_middleware.backends.kubernetes import KubernetesBackend
from netapp_middleware.catalogue import DEFAULT_CATALOGUE, Catalogue, parse_catalogue
from netapp_middleware.deployments import Registry
from netapp_middleware.services import Services
from netapp_middleware.switchover import Switchover

from tests.middleware.mw_helpers import NS, ROBOTS, EmulatedCluster, Kubelet, MiddlewareServer, Operator


@pytest.fixture()
def kube_api(tmp_path: Path) -> Iterator[EmulatedCluster]:
    """A Kubernetes API emulator on loopback with the NetApp CRD: `.url`, `.kube`, `.new_kube()`, `.kubeconfig`."""
    pytest.importorskip("kmock")
    cluster = EmulatedCluster(tmp_path)
    yield cluster
    cluster.close()


@pytest.fixture()
def robots_file(tmp_path: Path) -> Path:
    """The robots file of ROBOTS, hashed with cheap scrypt parameters to keep tests fast."""
    path = tmp_path / "robots.yaml"
    path.write_text(yaml.safe_dump({"robots": {rid: hash_secret(s, n=2**10) for rid, s in ROBOTS.items()}}))
    return path


@pytest.fixture()
def start_middleware(robots_file: Path) -> Iterator[Callable[..., MiddlewareServer]]:
    """Factory: start the middleware on a backend; all are stopped at teardown."""
    servers: list[MiddlewareServer] = []

    def start(
        backend: Backend,
        catalogue: dict[str, Any] | Callable[[], Catalogue] | None = None,
        token_ttl_s: float = 3600.0,
        max_per_robot: int = 16,
        switchover: dict[str, Any] | None = None,
        priorities: dict[str, str] | None = None,
        tracer: Any = None,
    ) -> MiddlewareServer:
        """`catalogue`: a catalogue document, or a source re-read at each call (`FileSource`); `switchover`: keyword
        arguments of `netapp_middleware.switchover.Switchover`; `priorities`: robot id -> its class, as the robots
        file would say."""
        catalogue_now: Callable[[], Catalogue]
        if callable(catalogue):
            catalogue_now = catalogue
        else:
            parsed = parse_catalogue(catalogue or DEFAULT_CATALOGUE)
            catalogue_now = lambda: parsed  # noqa: E731
        robots = parse_robots(yaml.safe_load(robots_file.read_text()))
        registry = Registry(backend, max_per_robot)
        services = Services(
            registry=registry,
            robots=RobotRegistry(lambda: robots, lambda: priorities or {}),
            signer=TokenSigner(ttl_s=token_ttl_s),
            catalogue=catalogue_now,
            switchover=Switchover(registry, catalogue_now, **(switchover or {})),
            tracer=tracer,
        )
        server = MiddlewareServer(services).__enter__()
        servers.append(server)
        return server

    yield start
    for server in reversed(servers):
        server.__exit__(None, None, None)


@pytest.fixture()
def cluster(kube_api: Any, start_middleware: Callable[..., MiddlewareServer]) -> tuple[str, Operator]:
    """The middleware on the kubernetes backend against kmock; yields its URL and the test's operator stand-in."""
    server = start_middleware(KubernetesBackend(NS, kube_api.new_kube()))
    return server.url, Operator(kube_api)


@pytest.fixture()
def kubelet(tiny_model_path: Path) -> Iterator[Kubelet]:
    """Serves real netapps (tiny model) on loopback for the kubernetes-backend tests; stops them at teardown."""
    kubelet = Kubelet(str(tiny_model_path))
    yield kubelet
    kubelet.close()
