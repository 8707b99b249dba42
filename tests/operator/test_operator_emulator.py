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
