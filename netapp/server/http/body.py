"""Reading what a request carries, bounded: its body (size and time) and the X-Timestamp header."""

from __future__ import annotations

import asyncio
import logging
import re
import time

from fastapi import Request
from starlette.requests import ClientDisconnect

from netapp.server.errors import FrameRejected

log = logging.getLogger(__name__)

TIMESTAMP = re.compile(r"-?[0-9]{1,20}")  # ASCII digits only: int() would take '²' and fail past 4300 digits
# What a timestamp may be on every transport (the frames header's is int64), and what a result's JSON can carry.
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1


async def read_limited(request: Request, limit: int, timeout_s: float, what: str = "frame") -> bytes:
    """The body, refusing more than `limit` bytes without reading it all into memory first (413), and a body
    that takes longer than `timeout_s` to arrive (408: a half-sent request must not hold memory forever). A client
    that goes away mid-upload is one log line, not a traceback."""
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and len(declared) < 20 and int(declared) > limit:
        raise FrameRejected("payload_too_large", f"{what} of {declared} bytes is over the {limit}-byte limit", 413)
    chunks, size = [], 0
    try:
        async with asyncio.timeout(timeout_s):
            async for chunk in request.stream():
                size += len(chunk)
                if size > limit:
                    raise FrameRejected("payload_too_large", f"{what} is over the {limit}-byte limit", 413)
                chunks.append(chunk)
    except TimeoutError:
        raise FrameRejected("body_timeout", f"the {what} did not arrive within {timeout_s:.0f} s", 408) from None
    except ClientDisconnect:
        client = f"{request.client.host}:{request.client.port}" if request.client else "a client"
        log.info("%s went away during its upload (%d bytes of %s received)", client, size, what)
        raise FrameRejected("client_disconnected", "the client went away during the upload", 400) from None
    return b"".join(chunks)


def parse_timestamp(text: str | None) -> int:
    """The X-Timestamp header (nanoseconds; now if absent); FrameRejected (422) unless a plain integer."""
    if text is None:
        return time.time_ns()
    if not TIMESTAMP.fullmatch(text) or not INT64_MIN <= (timestamp := int(text)) <= INT64_MAX:
        shown = text if len(text) <= 40 else text[:40] + "..."
        raise FrameRejected("bad_timestamp", f"X-Timestamp must be a 64-bit integer (nanoseconds), got {shown!r}", 422)
    return timestamp
