"""The Socket.IO client's reach past python-engineio's public API (`engineio_compat.RELIES_ON`) still exists in the
installed libraries: an upgrade that renames or drops one fails here, not on a robot."""

from __future__ import annotations

import importlib
import inspect
import re
from importlib.metadata import version

import engineio
import pytest
import socketio

from netapp.client.transports.engineio_compat import RELIES_ON, InOrderClient, InOrderEngineIOClient
from tests.support.paths import ROOT


def resolve(dotted: str) -> object:
    module, _, name = dotted.rpartition(".")
    return getattr(importlib.import_module(module), name)


def instance(owner: object) -> object:
    """An unconnected instance of `owner`, whose __init__ sets the instance attributes."""
    if owner is engineio.Client:
        return engineio.Client(handle_sigint=False)
    if owner is socketio.Client:
        return socketio.Client(handle_sigint=False)
    return owner()  # type: ignore[operator]


CASES = [(owner, kind, names) for owner, kinds in RELIES_ON.items() for kind, names in kinds.items()]


@pytest.mark.parametrize(("owner", "kind", "names"), CASES, ids=[f"{o}-{k}" for o, k, _ in CASES])
def test_what_the_override_relies_on_is_there(owner: str, kind: str, names: tuple[str, ...]) -> None:
    target = resolve(owner)
    if kind == "methods":
        missing = [n for n in names if not callable(getattr(target, n, None))]
    elif kind == "instance_attributes":
        obj = instance(target)
        missing = [n for n in names if not hasattr(obj, n)]
    else:
        _, _, method = kind.partition(":")
        function = getattr(target, method) if method else target
        missing = [n for n in names if n not in inspect.signature(function).parameters]  # type: ignore[arg-type]
    assert not missing, f"{owner} no longer has {kind} {missing}: see netapp/client/transports/engineio_compat.py"


def test_messages_are_triggered_asynchronously_and_websocket_options_reach_websocket_client() -> None:
    """The two call sites the override sits on: each message is `_trigger_event('message', ..., run_async=True)`
    (else the in-order dispatcher never runs), and `websocket_extra_options` go into `create_connection`
    (else `class_` would not take effect)."""
    receive = inspect.getsource(engineio.Client._receive_packet)
    assert re.search(r"_trigger_event\(\s*'message'.*run_async=True", receive), receive
    connect = inspect.getsource(engineio.Client._connect_websocket)
    assert "websocket_extra_options" in connect and "create_connection" in connect


def test_a_failed_engineio_connection_is_the_cause_of_socketios_error() -> None:
    """`engineio_failed` tells a WebSocket that did not get through from a refused namespace by the cause."""
    source = inspect.getsource(socketio.Client.connect)
    assert "except engineio.exceptions.ConnectionError as exc" in source
    assert "from exc" in source


def test_the_socketio_client_runs_on_the_in_order_engineio_client() -> None:
    assert type(InOrderClient(handle_sigint=False).eio) is InOrderEngineIOClient


def test_the_installed_versions_are_within_the_pinned_ranges() -> None:
    """The robot's dependencies in pyproject.toml bound python-engineio and python-socketio on both sides, and what
    is installed is inside."""
    tomllib = pytest.importorskip("tomllib")  # Python 3.11
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    requirements = pyproject["project"]["dependencies"]
    for package in ("python-engineio", "python-socketio"):
        pins = [r for r in requirements if re.match(rf"{package}(\[[^]]*\])?\s*[<>=!~]", r)]
        assert pins, f"{package} is not pinned in pyproject.toml"
        for pin in pins:
            low = re.search(r">=\s*([\d.]+)", pin)
            high = re.search(r"<\s*([\d.]+)", pin)
            assert low and high, f"{pin!r}: give both a lower and an upper bound"
            installed = tuple(int(p) for p in version(package).split(".")[:3])
            assert (
                tuple(int(p) for p in low.group(1).split("."))
                <= installed
                < tuple(int(p) for p in high.group(1).split("."))
            ), f"{package} {version(package)} is outside {pin!r}"
