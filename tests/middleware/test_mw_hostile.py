"""The middleware under hostile load: logins bounded and rate-limited, removed robots refused, keys checked, caps."""

from __future__ import annotations

import argparse
import asyncio
import threading
from concurrent.futures import ThreadPoolExecutor

import pytest
import requests
from netapp_middleware.auth import AuthError, RobotRegistry, TokenSigner, hash_secret
from netapp_middleware.catalogue import DEFAULT_CATALOGUE, parse_catalogue
from netapp_middleware.deployments import QuotaExceeded, Registry, with_token_digest
from netapp_middleware.login_guard import MAX_TRACKED, Busy, LoginGuard, TooManyFailures
from netapp_middleware.services import Services

from netapp.server.access import token_digest
from tests.middleware.mw_helpers import ROBOTS, MiddlewareServer, NullBackend


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture()
def robots() -> dict[str, str]:
    return {rid: hash_secret(secret, n=2**10) for rid, secret in ROBOTS.items()}


def test_failed_logins_are_rate_limited_per_robot_and_per_address(robots) -> None:
    clock = Clock()
    guard = LoginGuard(max_failures=3, window_s=60, clock=clock)
    registry = RobotRegistry(lambda: robots)
    for _ in range(3):
        with pytest.raises(AuthError):
            guard.authenticate(registry, "robot-1", "wrong", "10.0.0.1")
    clock.now += 20
    with pytest.raises(TooManyFailures, match="for this robot") as caught:  # even the right secret: no hashing
        guard.authenticate(registry, "robot-1", ROBOTS["robot-1"], "10.0.0.2")
    assert caught.value.retry_after_s == 40
    with pytest.raises(TooManyFailures, match="for this address"):  # the address is limited across robot ids
        guard.authenticate(registry, "robot-2", ROBOTS["robot-2"], "10.0.0.1")
    guard.authenticate(registry, "robot-2", ROBOTS["robot-2"], "10.0.0.3")  # others are not affected
    clock.now += 40  # the failures age out
    guard.authenticate(registry, "robot-1", ROBOTS["robot-1"], "10.0.0.1")
    assert guard.refused == 2


def test_the_failure_table_is_bounded(robots) -> None:
    guard = LoginGuard(max_failures=1, clock=Clock())
    for i in range(MAX_TRACKED + 10):
        guard._fail([f"robot:r{i}"])
    assert len(guard._failures) == MAX_TRACKED
    guard._check(["robot:r0"])  # forgotten: allowed again
    with pytest.raises(TooManyFailures):
        guard._check([f"robot:r{MAX_TRACKED + 9}"])


def test_hashing_runs_under_a_concurrency_limit() -> None:
    inside, release = threading.Semaphore(0), threading.Event()
    running = []

    class SlowRobots:
        def authenticate(self, robot_id: str, secret: str) -> None:
            running.append(robot_id)
            inside.release()
            release.wait(10)

    guard = LoginGuard(max_hashing=2, wait_s=0.2)
    with ThreadPoolExecutor(4) as pool:
        held = [pool.submit(guard.authenticate, SlowRobots(), f"r{i}", "s", None) for i in range(2)]
        assert inside.acquire(timeout=5) and inside.acquire(timeout=5)
        with pytest.raises(Busy, match="at most 2"):
            guard.authenticate(SlowRobots(), "r3", "s", None)
        release.set()
        for future in held:
            future.result(5)
    assert sorted(running) == ["r0", "r1"]


@pytest.fixture()
def middleware(robots):
    services = Services(
        registry=Registry(NullBackend(), max_per_robot=16, max_netapps=64),
        robots=RobotRegistry(lambda: robots),
        signer=TokenSigner(),
        catalogue=lambda: parse_catalogue(DEFAULT_CATALOGUE),
        logins=LoginGuard(max_failures=3),
    )
    with MiddlewareServer(services) as server:
        yield server


def login(url: str, robot_id: str, secret: str) -> requests.Response:
    return requests.post(f"{url}/auth/token", json={"robot_id": robot_id, "secret": secret}, timeout=10)


def test_over_http_a_login_flood_gets_429_with_retry_after(middleware) -> None:
    url = middleware.url
    assert [login(url, "robot-1", "wrong").status_code for _ in range(3)] == [401] * 3
    refused = login(url, "robot-1", ROBOTS["robot-1"])
    assert refused.status_code == 429 and 0 < int(refused.headers["Retry-After"]) <= 60
    assert "too many failed logins" in refused.text
    era = requests.post(f"{url}/Login", json={"Id": "robot-2", "Password": ROBOTS["robot-2"]}, timeout=10)
    assert era.status_code == 429 and "Retry-After" in era.headers and era.json()["errors"]  # same address
    assert requests.get(f"{url}/healthz", timeout=5).status_code == 200


def test_a_robot_removed_from_the_robots_file_is_refused_whatever_token_it_holds(middleware, robots) -> None:
    url = middleware.url
    token = login(url, "robot-1", ROBOTS["robot-1"]).json()["access_token"]
    headers = {"Authorization": f"Bearer {token}"}
    assert requests.get(f"{url}/deployments", headers=headers, timeout=5).status_code == 200
    del robots["robot-1"]
    refused = requests.get(f"{url}/deployments", headers=headers, timeout=5)
    assert refused.status_code == 401 and "no longer registered" in refused.text
    assert requests.post(f"{url}/auth/refresh", headers=headers, timeout=5).status_code == 401


def test_a_token_with_non_ascii_characters_is_a_401_not_a_500(middleware) -> None:
    for token in ("abc.d\u00e9f", "\u00e9", "x.\u00b2"):
        r = requests.get(
            f"{middleware.url}/deployments", headers={"Authorization": f"Bearer {token}".encode()}, timeout=5
        )
        assert r.status_code == 401, (token, r.status_code, r.text)
    with pytest.raises(AuthError):
        TokenSigner().verify("p\u00e9.sig\u00e9")


@pytest.mark.parametrize("key", [b"", b"x" * 31])
def test_a_short_token_key_is_refused(key: bytes) -> None:
    with pytest.raises(ValueError, match="at least 32"):
        TokenSigner(key)
    TokenSigner(b"k" * 32)


def test_serve_refuses_a_short_token_key_with_one_line(tmp_path, monkeypatch, caplog) -> None:
    from netapp_middleware.cli import add_arguments
    from netapp_middleware.server import serve

    monkeypatch.setenv("NETAPP_MIDDLEWARE_TOKEN_KEY", "")
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["--port", "0"])
    args.log_level = "INFO"
    assert serve(args) == 2
    assert "token key has 0 bytes, at least 32" in caplog.text


async def test_netapps_are_capped_across_robots() -> None:
    registry = Registry(NullBackend(), max_per_robot=2, max_netapps=3)
    app = parse_catalogue(DEFAULT_CATALOGUE).get("object-detection")
    shared = registry.create("a", app, None, True)
    for robot in ("a", "b"):
        registry.create(robot, app, None, False)
    with pytest.raises(QuotaExceeded, match="limit of 3 NetApps for all robots"):
        registry.create("c", app, None, False)
    assert registry.create("c", app, None, True).instance is shared.instance  # sharing adds no NetApp


async def test_an_app_without_unauthenticated_access_gets_a_token_per_netapp() -> None:
    signer = TokenSigner(b"k" * 32)
    registry = Registry(NullBackend(), token_for=signer.netapp_token)
    catalogue = parse_catalogue(
        {
            "open": {"spec": {"image": "x"}},
            "closed": {"spec": {"image": "x", "env": [{"name": "A", "value": "1"}]}, "allowUnauthenticated": False},
        }
    )
    assert "token" not in registry.create("r1", catalogue.get("open"), None, True).view()
    first = registry.create("r1", catalogue.get("closed"), None, True)
    token = first.view()["token"]
    assert token == signer.netapp_token(first.instance.name)  # a restarted middleware derives the same one
    assert registry.create("r2", catalogue.get("closed"), None, True).view()["token"] == token  # shared: same netapp
    spec = with_token_digest({"image": "x", "env": [{"name": "A", "value": "1"}]}, token)
    assert spec["env"] == [{"name": "A", "value": "1"}, {"name": "NETAPP_TOKEN_SHA256", "value": token_digest(token)}]
    with pytest.raises(ValueError, match="allowUnauthenticated"):
        parse_catalogue({"x": {"spec": {"image": "x"}, "allowUnauthenticated": "no"}})
    await asyncio.sleep(0)  # let the registry's create tasks run


def test_the_middleware_hands_the_netapp_token_to_the_robot(start_middleware, tiny_model_path, jpeg) -> None:
    """End to end on the local backend: the netapp refuses robots without its token; MiddlewareClient passes it on."""
    import queue

    from netapp_middleware.backends.local import LocalBackend

    from netapp.client.middleware import MiddlewareClient
    from tests.middleware.mw_helpers import DEADLINE_S, send_until_result

    catalogue = {"guarded": {"spec": {"image": "x"}, "allowUnauthenticated": False}}
    server = start_middleware(LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S), catalogue)
    with MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as mw:
        endpoint = mw.deploy("guarded", timeout=2 * DEADLINE_S)
        assert endpoint.token
        refused = requests.post(f"{endpoint.url}/register", json={}, timeout=5)
        assert refused.status_code == 401 and refused.json()["reason"] == "unauthorized"
        for transport in ("http", "ws"):
            results: queue.Queue = queue.Queue()
            with mw.netapp_client(endpoint, transport=transport, on_result=results.put) as client:
                assert send_until_result(lambda c=client: c.send(jpeg), results).detections
