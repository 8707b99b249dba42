"""Priority classes from the robots file: the middleware hands each robot its class's token for the NetApp, and the
NetApp takes it for that class (and no robot can claim a class whose token it was not given)."""

from __future__ import annotations

import asyncio

import pytest
from netapp_middleware.auth import TokenSigner, hash_secret, parse_robots, robot_priorities
from netapp_middleware.catalogue import parse_catalogue
from netapp_middleware.deployments import Registry

from netapp.protocol import PRIORITY_TOKENS_ENV
from netapp.server.access import token_digest
from tests.middleware.mw_helpers import DEADLINE_S, ROBOTS, NullBackend


def test_the_robots_file_may_give_a_robot_a_class():
    h = hash_secret("s", n=2**10)
    document = {"robots": {"r1": {"secretHash": h, "priority": "high"}, "r2": h}}
    assert parse_robots(document) == {"r1": h, "r2": h}
    assert robot_priorities(document) == {"r1": "high"}
    assert robot_priorities({"robots": [{"id": "r1", "secretHash": h, "priority": 0}]}) == {"r1": "low"}
    with pytest.raises(ValueError, match="priority must be one of low, normal, high"):
        robot_priorities({"r1": {"secretHash": h, "priority": "vip"}})
    with pytest.raises(ValueError, match="needs a secretHash"):
        parse_robots({"r1": {"priority": "high"}})


async def test_each_robot_gets_its_classs_token_and_the_netapp_their_digests():
    signer = TokenSigner(b"k" * 32)
    created: list[dict] = []

    class Recording(NullBackend):
        async def create(self, name, app, placement, spec, labels, annotations=None):
            created.append(spec)
            return await super().create(name, app, placement, spec, labels)

    registry = Registry(Recording(), token_for=signer.netapp_token)
    app = parse_catalogue({"guarded": {"spec": {"image": "x"}, "allowUnauthenticated": False}}).get("guarded")
    high = registry.create("r1", app, None, True, {"priority": "high"}).view()
    normal = registry.create("r2", app, None, True, {"priority": "normal"}).view()
    name = registry.list("r1")[0].instance.name
    assert normal["token"] == signer.netapp_token(name)  # the NetApp's own
    assert high["token"] == signer.netapp_token(f"{name}:high") != normal["token"]  # derived: same after a restart
    await asyncio.sleep(0)  # let the registry's create task run
    env = {e["name"]: e["value"] for e in created[0]["env"]}
    assert env[PRIORITY_TOKENS_ENV] == ",".join(
        f"{c}={token_digest(signer.netapp_token(f'{name}:{c}'))}" for c in ("high", "low")
    )
    assert high["token"] not in str(created[0])  # digests only


def test_a_robot_the_robots_file_makes_high_is_high_on_its_netapp(start_middleware, tiny_model_path):
    from netapp_middleware.backends.local import LocalBackend

    from netapp.client import NetAppRefused
    from netapp.client.middleware import MiddlewareClient

    catalogue = {"shared": {"spec": {"image": "x"}}}  # open to robots without a token: class tokens still count
    server = start_middleware(
        LocalBackend(model=str(tiny_model_path), ready_timeout_s=2 * DEADLINE_S),
        catalogue,
        priorities={"robot-1": "high"},
    )
    with (
        MiddlewareClient(server.url, "robot-1", ROBOTS["robot-1"]) as first,
        MiddlewareClient(server.url, "robot-2", ROBOTS["robot-2"]) as second,
    ):
        mine, theirs = first.deploy("shared", timeout=2 * DEADLINE_S), second.deploy("shared", timeout=2 * DEADLINE_S)
        assert mine.url == theirs.url and mine.token and not theirs.token  # one NetApp; only robot-1 has a token
        with first.netapp_client(mine, transport="ws", args={"priority": "high"}) as client:
            assert client.session_id  # its token grants high
        with pytest.raises(NetAppRefused) as refused:
            second.netapp_client(theirs, transport="ws", args={"priority": "high"}).connect()
        assert refused.value.reason == "priority_not_allowed"
