"""Subscribe to a camera a netapp pulls (`netapp serve --source NAME=rtsp://...`) and get its results: one `frames`
WebSocket, a WATCH command, then `results` events (docs/cameras.md#results). The protocol is the I/O-free
`netapp.frames_session.FramesSession`; this file is its I/O. Imports no server code."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

from websockets.exceptions import ConnectionClosed, InvalidHandshake
from websockets.sync.client import ClientConnection, connect

from netapp.client.delivery import Result
from netapp.client.errors import ConnectionLost, NetAppError, NetAppRefused, refusal
from netapp.client.transports import bearer_headers
from netapp.frames_session import Acked, FramesSession, Moved, Refused, Results
from netapp.framing import frames_url
from netapp.protocol import ELSEWHERE_REASON, SOURCE_FIELD, CommandType
from netapp.reconnect import ReconnectPolicy

OPEN_TIMEOUT_S = 10.0


class Subscription:
    """One camera's results from one netapp: `results()` yields them; `close()` (from any thread) ends it."""

    def __init__(self, url: str, source: str, token: str | None = None, timeout_s: float = OPEN_TIMEOUT_S) -> None:
        self.url, self.source = url, source
        self._protocol = FramesSession()
        try:
            self._ws: ClientConnection = connect(
                frames_url(url),
                additional_headers=bearer_headers(token),
                open_timeout=timeout_s,
                **self._protocol.socket_options(),
            )
        except (OSError, InvalidHandshake, TimeoutError) as exc:
            raise NetAppError(f"cannot reach {url}: {exc}") from exc
        self._closed = False
        self._ack: bool | None = None  # WATCH was acknowledged
        self._early: list[dict[str, Any]] = []  # results read while waiting for the acknowledgement (bounded by it)
        self._ws.send(self._protocol.command(CommandType.WATCH, {SOURCE_FIELD: source}).text)

    def accepted(self, timeout_s: float = OPEN_TIMEOUT_S) -> None:
        """Wait for WATCH's acknowledgement: NetAppRefused when it is refused (results that come first are kept)."""
        deadline = time.monotonic() + timeout_s
        while self._ack is None:
            try:
                text = self._ws.recv(timeout=max(0.0, deadline - time.monotonic()))
            except TimeoutError:
                raise NetAppError(f"{self.url} did not answer WATCH within {timeout_s:.0f} s") from None
            except ConnectionClosed as exc:
                raise ConnectionLost(f"{self.url} closed the connection: {exc}") from exc
            result = self._read(text)
            if result is not None:
                self._early.append(result)

    def results(self, until: float | None = None) -> Iterator[dict[str, Any]]:
        """Each result, with `source` in it, until `until` (time.monotonic()) passes or `close()`. NetAppRefused:
        no such camera, a wrong token; ConnectionLost when the netapp goes away."""
        while self._early:
            yield self._early.pop(0)
        try:
            while until is None or time.monotonic() < until:
                try:
                    text = self._ws.recv(timeout=None if until is None else max(0.0, until - time.monotonic()))
                except TimeoutError:
                    return
                result = self._read(text)
                if result is not None:
                    yield result
        except ConnectionClosed as exc:
            if not self._closed:
                raise ConnectionLost(f"{self.url} closed the connection: {exc}") from exc

    def _read(self, text: Any) -> dict[str, Any] | None:
        got = self._protocol.receive(text)
        if isinstance(got, Acked) and got.ok:
            self._ack = True
        elif isinstance(got, (Acked, Refused)):
            body = got.answer if isinstance(got, Acked) else got.body
            raise refusal(self.url, body, _text(body))
        elif isinstance(got, Moved):
            raise ConnectionLost(f"{self.url} is going away (draining): watch again through the Service")
        elif isinstance(got, Results):
            return got.data
        return None

    def close(self) -> None:
        self._closed = True
        self._ws.close()

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


ELSEWHERE_TRIES = 20  # behind a Service, each new connection reaches a replica at random


def elsewhere_policy() -> ReconnectPolicy:
    """How long `subscribe` waits before it connects again: a second (each connection reaches a replica at random,
    so waiting longer finds the camera's no sooner), or the netapp's own Retry-After, bounded to 5 s."""
    return ReconnectPolicy(first_s=0.0, max_s=1.0, floor_s=0.5, retry_after_max_s=5.0)


def subscribe(url: str, source: str, token: str | None = None) -> Subscription:
    """A Subscription whose WATCH was accepted. Behind a Service of several replicas, only the one holding the
    camera's Lease takes it (`elsewhere`): connect again, up to ELSEWHERE_TRIES times, each as the netapp asks."""
    policy = elsewhere_policy()
    policy.next_s()  # the first try goes at once
    for attempt in range(ELSEWHERE_TRIES):
        subscription = Subscription(url, source, token)
        try:
            subscription.accepted()
            return subscription
        except NetAppRefused as exc:
            subscription.close()
            if exc.reason != ELSEWHERE_REASON or attempt == ELSEWHERE_TRIES - 1:
                raise
            time.sleep(policy.next_s(exc.retry_after_s))
    raise AssertionError("unreachable")


def camera_result(message: dict[str, Any], url: str) -> Result | None:
    """A camera's result message as the robot's outputs take it (`netapp stream --jsonl/--mcap`'s sinks): stamped with
    when the netapp decoded the picture; its latency the netapp's own, receive to send (the camera's clock is not
    ours). None for a message without an integer timestamp."""
    timestamp = message.get("timestamp")
    if not isinstance(timestamp, int) or isinstance(timestamp, bool):
        return None
    detections = message.get("detections")
    received, sent = message.get("recv_timestamp"), message.get("send_timestamp")
    netapp_ms = (sent - received) / 1e6 if isinstance(received, int) and isinstance(sent, int) else 0.0
    return Result(
        timestamp,
        detections if isinstance(detections, list) else [],
        netapp_ms,
        message,
        source=url,
        source_stamp_ns=timestamp,
    )


def _text(body: Any) -> str:
    """The message of a refusal, bounded (a hostile netapp must not flood the terminal)."""
    if isinstance(body, dict):
        return str(body.get("message") or body.get("error") or body)[:500]
    return str(body)[:500]
