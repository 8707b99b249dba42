"""The robot client's errors, and reading the error body of an HTTP answer (netapp and middleware alike)."""

from __future__ import annotations

import requests

from netapp.protocol import error_message

# An error body is shown to a person and kept in `ClientStats.last_error`: a hostile or broken server must not make
# either grow without bound.
MAX_ERROR_TEXT = 500


class NetAppError(Exception):
    """The netapp could not be reached or refused the session."""


def response_error(response: requests.Response) -> str:
    """The message of a non-2xx answer: its body's `error` (`netapp.protocol.error_body`), else the body's text."""
    try:
        body = response.json()
    except ValueError:
        body = None
    return error_message(body, fallback=response.text[:MAX_ERROR_TEXT])[:MAX_ERROR_TEXT]


def response_reason(response: requests.Response) -> str | None:
    """The `reason` code of a non-2xx answer's error body (`netapp.protocol.error_body`), None without one."""
    try:
        body = response.json()
    except ValueError:
        return None
    reason = body.get("reason") if isinstance(body, dict) else None
    return reason[:MAX_ERROR_TEXT] if isinstance(reason, str) else None
