"""The API emulator's own dispatch (tests/support/kmock_dispatch.py): the reaction kmock would pick, without
scanning the requests in flight."""

from __future__ import annotations

import asyncio
from typing import Any

import aiohttp
import pytest

kmock = pytest.importorskip("kmock", reason="kmock is not installed (pip install '.[test]')")

from tests.support.kmock_dispatch import CriteriaMemo, sees  # noqa: E402


async def test_sees_agrees_with_kmocks_scan_while_other_requests_are_in_flight(emulator):
    views = {
        "get": emulator["get"],
        "post": emulator["post"],
        "get /probe": emulator["get /probe"],
        "callable": emulator["get"][lambda r: r.params.get("q") == "1"],
        "or": emulator["post"] | emulator["get /probe"],
        "and": emulator["get"] & emulator["/probe"],
        "exclusion": emulator["get"] - emulator["/probe"],
        "fallback": emulator.fallback["get"],
    }
    answers: dict[str, tuple[dict[str, bool], ...]] = {}
    memo = CriteriaMemo()  # shared by both probes: the second one is answered from the first one's verdicts
    release = asyncio.Event()

    async def hold(request: Any) -> Any:
        await release.wait()  # keeps this request in flight while the probes are answered
        return {"held": True}

    async def probe(request: Any) -> Any:
        answers[request.params["q"]] = (
            {name: sees(view, request, emulator) for name, view in views.items()},
            {name: request in view for name, view in views.items()},
            {name: sees(view, request, emulator, memo) for name, view in views.items()},
        )
        return {"probed": True}

    emulator["get /hold"] << hold
    emulator["get /probe"] << probe
    base = str(emulator.url).rstrip("/")
    async with aiohttp.ClientSession() as http:

        async def get(path: str) -> Any:
            async with http.get(base + path) as response:
                return await response.json()

        held = [asyncio.create_task(get("/hold")) for _ in range(3)]
        probes = await asyncio.gather(get("/probe?q=1"), get("/probe?q=2"))
        release.set()
        assert await asyncio.gather(*held) == [{"held": True}] * 3
    assert probes == [{"probed": True}] * 2
    assert sorted(answers) == ["1", "2"]
    for fast, scanned, remembered in answers.values():
        assert fast == scanned == remembered
    assert answers["1"][0]["callable"] and not answers["2"][0]["callable"]
    assert answers["1"][0]["or"] and not answers["1"][0]["exclusion"] and not answers["1"][0]["post"]


async def test_a_declared_reaction_overrides_the_emulators_fallback(emulator):
    emulator["get /version"] << {"major": "9", "minor": "99"}  # a plain reaction outranks the fallback
    base = str(emulator.url).rstrip("/")
    async with aiohttp.ClientSession() as http:
        async with http.get(base + "/version") as response:
            assert (await response.json())["minor"] == "99"
        async with http.get(base + "/api/v1/namespaces/x/services/missing") as response:
            assert response.status == 404  # the emulator's own fallback still answers the rest


async def test_kmocks_callbacks_signatures_are_remembered_and_its_json_is_the_same():
    """tests/support/kmock_rendering.py: kmock asks a callback's signature once, and its JSON reads the same."""
    import inspect
    import json

    from kmock._internal import rendering

    from tests.support.kmock_rendering import dumps, lighten_rendering, signature

    class Holder:
        def serve(self, request: Any) -> None: ...

    lighten_rendering()
    assert rendering.inspect.signature is signature and rendering.json.dumps is dumps
    assert rendering.inspect.GEN_CREATED == inspect.GEN_CREATED  # the rest of the module as it was
    for callback in (Holder().serve, Holder.serve, lambda: None, print):
        assert signature(callback) == inspect.signature(callback)
    assert signature(Holder().serve) is signature(Holder().serve)  # per function, whatever the object
    body = {"a": [1, 2.5, None, True], "b": {"c": "é"}}
    assert json.loads(dumps(body)) == body
    assert dumps({1: "x"}) == json.dumps({1: "x"})  # what orjson refuses goes to json
    response = rendering.aiohttp.web.json_response(body)
    assert response.content_type == "application/json" and json.loads(response.text) == body


async def test_a_watch_bus_keeps_a_bounded_number_of_read_events(emulator):
    """tests/support/kube_emulator.py's `_WatchBus`: events every watch has read are freed by the few hundred."""
    from tests.support.kube_emulator import WATCH_BUFFER

    bus = emulator._buses["anything"]
    marker = await bus.mark()
    for i in range(WATCH_BUFFER * 3):
        await bus.put(i)
        assert await bus.get(since=marker) == i
        assert bus.buffer_size <= WATCH_BUFFER
    assert bus.removed_count >= WATCH_BUFFER * 2
