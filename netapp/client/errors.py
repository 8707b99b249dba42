"""The robot client's errors, and reading the error body of an HTTP answer (netapp and middleware alike)."""

from __future__ import annotations

import requests

from netapp.protocol import (
    DRAINING_REASON,
    MAX_RETRY_AFTER_S,
    SESSIONS_FULL_REASON,
    UNAUTHORIZED_REASON,
    error_message,
)

# An error body is shown to a person and kept in `ClientStats.last_error`: a hostile or broken server must not make
# either grow without bound.
MAX_ERROR_TEXT = 500


class NetAppError(Exception):
    """The netapp could not be reached or refused the session."""


class OutputError(Exception):
    """An output of results cannot be opened (a path not writable, no display): the sinks of `netapp stream` and
    `netapp watch` (netapp/apps/outputs.py) and the ROS recorders (netapp/ros/recorder.py) raise it."""


REFUSALS = {  # the netapp's `reason` of a refused session -> how the robot's message names it
    SESSIONS_FULL_REASON: "sessions full",
    DRAINING_REASON: "draining",
    UNAUTHORIZED_REASON: "bad token",
}


class NetAppRefused(NetAppError):
    """The netapp answered, and refused the session: `reason` (sessions_full, draining, unauthorized), its session
    `limit` (sessions_full) and `retry_after_s` (when it may take the robot, if it said), `url` and its `detail`
    (the netapp's own words). Raised at once, never turned into a timeout (`docs/client.md#when-a-netapp-refuses`)."""

    def __init__(
        self,
        url: str,
        reason: str,
        detail: str = "",
        *,
        limit: int | None = None,
        retry_after_s: float | None = None,
    ) -> None:
        self.url, self.reason, self.detail = url, reason, detail[:MAX_ERROR_TEXT]
        self.limit, self.retry_after_s = limit, retry_after_s
        facts = [f"limit {limit}"] if limit is not None else []
        if retry_after_s is not None:
            facts.append(f"retry after {retry_after_s:g} s")
        said = f" ({', '.join(facts)})" if facts else ""
        said = f"{REFUSALS[reason]}{said}" if reason in REFUSALS else self.detail or reason
        if reason == UNAUTHORIZED_REASON and self.detail:  # how to present the token, in the netapp's words
            said = f"{said}: {self.detail}"
        super().__init__(f"{url} refused: {said}")


def refusal(url: str, fields: dict, detail: str = "") -> NetAppRefused:
    """A `NetAppRefused` from the machine-readable fields of a netapp's refusal (an HTTP error body, a Socket.IO
    `command_error` or connect error): `reason`, `limit`, `retry_after_s`."""
    limit, retry = fields.get("limit"), fields.get("retry_after_s")
    return NetAppRefused(
        url,
        str(fields.get("reason") or "refused")[:MAX_ERROR_TEXT],
        detail or str(fields.get("error") or ""),
        limit=limit if isinstance(limit, int) and not isinstance(limit, bool) else None,
        retry_after_s=float(retry) if isinstance(retry, (int, float)) and not isinstance(retry, bool) else None,
    )


class ConnectionLost(NetAppError):
    """The connection dropped as a frame was put on the wire: the frame is lost, like those in flight."""


def response_refusal(url: str, response: requests.Response) -> NetAppRefused | None:
    """The refusal a `/register` answer carries (503 sessions_full or draining with Retry-After, 401), else None."""
    reason = UNAUTHORIZED_REASON if response.status_code == 401 else response_reason(response)
    if reason not in REFUSALS:
        return None
    try:
        body = response.json()
    except ValueError:
        body = None
    fields = dict(body) if isinstance(body, dict) else {}
    fields.update(reason=reason, retry_after_s=retry_after_s(response))
    return refusal(url, fields, response_error(response))


def response_error(response: requests.Response) -> str:
    """The message of a non-2xx answer: its body's `error` (`netapp.protocol.error_body`), else the body's text."""
    try:
        body = response.json()
    except ValueError:
        body = None
    return error_message(body, fallback=response.text[:MAX_ERROR_TEXT])[:MAX_ERROR_TEXT]


MIN_RETRY_S = 0.05  # a Retry-After of 0 still yields to the netapp for a moment


def response_reason(response: requests.Response) -> str | None:
    """The `reason` code of a non-2xx answer's error body (`netapp.protocol.error_body`), None without one."""
    try:
        body = response.json()
    except ValueError:
        return None
    reason = body.get("reason") if isinstance(body, dict) else None
    return reason[:MAX_ERROR_TEXT] if isinstance(reason, str) else None


def retry_after_s(response: requests.Response, longest_s: float = MAX_RETRY_AFTER_S) -> float | None:
    """Seconds to wait before trying again, for a 503 that says so (`Retry-After` in seconds); None otherwise."""
    value = response.headers.get("Retry-After", "") if response.status_code == 503 else ""
    if not value.strip().isdigit():
        return None
    return min(longest_s, max(MIN_RETRY_S, float(value)))
