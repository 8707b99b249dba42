"""kmock's rendering of a response at a lower cost: test scaffolding for `kube_emulator.Emulator`.

kmock 0.8 asks `inspect.signature(callback)` on every request it answers with a callback (whether to pass the
request to it), for the same half-dozen callbacks every time (the emulator's `_serve_*` methods), and encodes every
answer and watch event with `json`: 10 % and 7 % of the emulator's CPU in a burst of 4,000 NetApps (py-spy,
bench/operator_bench.py). `lighten_rendering` gives kmock's rendering module an `inspect` that remembers each
callback's signature (it does not change) and JSON encoded by orjson (the same JSON, without the spaces; whatever
orjson refuses goes to `json` as before).
"""

from __future__ import annotations

import inspect
import json
import types
import weakref
from collections.abc import Callable
from typing import Any

import aiohttp.web
import orjson
from kmock._internal import rendering

# Per function, weakly (a test's callbacks go with the test): a bound method's signature is its function's less the
# first parameter whatever the object, so bound methods are remembered by their function, apart from plain ones.
_BOUND: weakref.WeakKeyDictionary[Any, inspect.Signature] = weakref.WeakKeyDictionary()
_PLAIN: weakref.WeakKeyDictionary[Any, inspect.Signature] = weakref.WeakKeyDictionary()


def signature(callback: Callable[..., Any]) -> inspect.Signature:
    """`inspect.signature`, remembered per callback."""
    bound = isinstance(callback, types.MethodType)
    memo, key = (_BOUND, callback.__func__) if bound else (_PLAIN, callback)
    try:
        found = memo.get(key)
    except TypeError:  # not weakly referable, or unhashable: not remembered
        return inspect.signature(callback)
    if found is None:
        found = memo[key] = inspect.signature(callback)
    return found


def dumps(obj: Any, **kwargs: Any) -> str:
    """`json.dumps` by orjson where it can (kmock passes no options)."""
    if not kwargs:
        try:
            return orjson.dumps(obj).decode()
        except TypeError:  # orjson.JSONEncodeError: e.g. a key that is not a string, which json accepts
            pass
    return json.dumps(obj, **kwargs)


class _Inspect(types.ModuleType):
    """The `inspect` module with a remembering `signature`."""

    signature = staticmethod(signature)

    def __getattr__(self, name: str) -> Any:
        return getattr(inspect, name)


class _Json(types.ModuleType):
    """The `json` module whose `dumps` is orjson's where it can."""

    dumps = staticmethod(dumps)

    def __getattr__(self, name: str) -> Any:
        return getattr(json, name)


class _Web(types.ModuleType):
    """`aiohttp.web` whose `json_response` encodes with orjson where it can."""

    @staticmethod
    def json_response(*args: Any, **kwargs: Any) -> aiohttp.web.Response:
        return aiohttp.web.json_response(*args, **{"dumps": dumps, **kwargs})

    def __getattr__(self, name: str) -> Any:
        return getattr(aiohttp.web, name)


class _Aiohttp(types.ModuleType):
    web = _Web("aiohttp.web")

    def __getattr__(self, name: str) -> Any:
        return getattr(aiohttp, name)


def lighten_rendering() -> None:
    """Install the remembering `inspect` and orjson's JSON in kmock's rendering module (idempotent)."""
    if not isinstance(rendering.inspect, _Inspect):
        rendering.inspect = _Inspect("inspect")
        rendering.json = _Json("json")
        rendering.aiohttp = _Aiohttp("aiohttp")
