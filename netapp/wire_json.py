"""JSON on the data path, one codec for both sides and every transport: results, `frames` events and commands,
Socket.IO packets, HTTP result bodies. orjson, not the standard library: a result of 30 detections is
encoded in 8 µs against 67 and parsed in 9 against 52 (docs/benchmarks.md#json-on-the-data-path-issue-24).

The text is the same JSON, with three differences, each on the safe side: NaN and the infinities become `null` (the
standard library writes `NaN`, which no JSON parser but Python's reads), numpy scalars and arrays are written as
numbers and lists (a custom processor may return them), and non-string keys as strings (as the standard library
does). What cannot be encoded raises TypeError, as there.
"""

from __future__ import annotations

from typing import Any

import orjson

OPTIONS = orjson.OPT_NON_STR_KEYS | orjson.OPT_SERIALIZE_NUMPY
JSONDecodeError = orjson.JSONDecodeError  # a ValueError, as json's


def dumpb(obj: Any) -> bytes:
    """`obj` as compact JSON, UTF-8."""
    return orjson.dumps(obj, option=OPTIONS)


def dumps(obj: Any, **_json_options: Any) -> str:
    """`obj` as compact JSON text. Takes and ignores `json.dumps`' options, so python-socketio and python-engineio can
    use this module as their `json` (they ask for compact separators, which this always is)."""
    return dumpb(obj).decode()


def loads(data: str | bytes | bytearray | memoryview, **_json_options: Any) -> Any:
    """JSON text or UTF-8 bytes -> Python objects; JSONDecodeError (a ValueError) when it is not JSON."""
    return orjson.loads(data)
