"""The HTTP transport: register, then one `POST /send_image?wait=true` per frame, answered with its result."""

from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import requests
import urllib3

from netapp import wire_json
from netapp.client.errors import NetAppError, response_error, response_reason, response_refusal
from netapp.client.transports import SessionSettings, TransportCallbacks, environment_settings
from netapp.frame import JPEG, EncodedFrame
from netapp.protocol import DEADLINE_HEADER, DRAINING_REASON, ROBOT_LATENCY_HEADER
from netapp.tracecontext import TRACEPARENT, TRACESTATE

log = logging.getLogger(__name__)

CONTENT_TYPES = {JPEG: "image/jpeg"}  # what the netapp's /send_image takes


class HttpTransport:
    """A session registered with one netapp; frames are posted from a pool of `max_in_flight` threads."""

    def __init__(self, url: str, settings: SessionSettings, callbacks: TransportCallbacks) -> None:
        self.url = url
        self.settings = settings
        self.callbacks = callbacks
        self._session_id: str | None = None
        self._pool: ThreadPoolExecutor | None = None
        self._frames: FramePoster | None = None
        self._closed = False

    @property
    def session_id(self) -> str | None:
        return self._session_id

    def connect(self) -> None:
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.settings.max_in_flight, thread_name_prefix="netapp-http")
            self._frames = FramePoster(self.url, self.settings)
        self._register()

    def transmit(self, frame: EncodedFrame) -> None:
        content_type = CONTENT_TYPES.get(frame.codec)
        if content_type is None:
            raise ValueError(f"the HTTP transport carries {sorted(CONTENT_TYPES)} frames, not {frame.codec}")
        if self._pool is None:
            raise NetAppError("the HTTP transport is not connected")
        self._pool.submit(self._post, frame, content_type)

    def close(self) -> None:
        self._closed = True
        if self._pool is not None:
            # Posts under way end by themselves (their answers are ignored now); queued ones are dropped.
            self._pool.shutdown(wait=False, cancel_futures=True)
        if self._frames is not None:
            self._frames.close()
        session_id, self._session_id = self._session_id, None
        if session_id:
            try:
                headers = {"X-Session-Id": session_id, **self.settings.auth_headers()}
                requests.post(f"{self.url}/unregister", headers=headers, timeout=2)
            except requests.RequestException:
                pass

    def _register(self) -> None:
        """Register; a refusal (503 sessions_full or draining, 401) raises `NetAppRefused` at once: the link decides
        whether to try again after its Retry-After (`netapp.client.link`)."""
        try:
            response = requests.post(
                f"{self.url}/register",
                json={"robot_id": self.settings.robot_id, "args": self.settings.args},
                headers=self.settings.auth_headers(),
                timeout=self.settings.connect_timeout_s,
            )
        except requests.RequestException as exc:
            raise NetAppError(f"cannot register with {self.url}: {exc}") from exc
        refused = response_refusal(self.url, response)
        if refused is not None:
            raise refused
        if not response.ok:
            raise NetAppError(f"cannot register with {self.url}: {response.status_code} {response_error(response)}")
        answer = response.json()
        self._session_id = answer["session_id"]
        self.callbacks.on_session_info(answer)
        state = self.callbacks.state_to_restore()
        if state is not None:
            self._restore(state)
        self.callbacks.on_ready()

    def _restore(self, state: Any) -> None:
        """PUT /state before the first frame; a refusal is reported and the session starts from a fresh state."""
        try:
            response = requests.put(
                f"{self.url}/state",
                json=state,
                headers={"X-Session-Id": self._session_id or "", **self.settings.auth_headers()},
                timeout=self.settings.connect_timeout_s,
            )
            ok = response.status_code == 204
            message = "state set" if ok else response_error(response)
        except requests.RequestException as exc:
            ok, message = False, f"PUT /state failed: {exc}"
        if not ok:
            log.warning("the netapp did not take the session state: %s", message)
        self.callbacks.on_restored(ok, message)

    def _post(self, frame: EncodedFrame, content_type: str) -> None:
        timestamp = frame.timestamp
        assert self._frames is not None
        try:
            response = self._frames.post(frame.payload, self._headers(frame, content_type))
        except urllib3.exceptions.HTTPError as exc:
            if not self._closed:
                self.callbacks.on_error({"timestamp": timestamp, "error": f"request failed: {exc}"})
            return
        if self._closed:
            return
        if response.status_code == 200:
            self.callbacks.on_result(response.json())
        elif response.status_code == 409:
            self.callbacks.on_dropped(timestamp)
        elif response.status_code == 503 and response_reason(response) == DRAINING_REASON:
            self.callbacks.on_move(DRAINING_REASON)  # this frame is one of those in flight, counted lost
        else:
            self.callbacks.on_error(
                {
                    "timestamp": timestamp,
                    "error": response_error(response),
                    "reason": response_reason(response),
                    "status": response.status_code,
                }
            )
            if response.status_code in (404, 410):  # the netapp restarted or expired us: register again
                try:
                    self._register()
                except NetAppError as exc:
                    log.warning("%s", exc)

    def _headers(self, frame: EncodedFrame, content_type: str) -> dict[str, str]:
        """The frame's edge: what the body does not carry goes in headers."""
        headers = {
            "X-Session-Id": self._session_id or "",
            "X-Timestamp": str(frame.timestamp),
            "Content-Type": content_type,
        }
        if frame.deadline_ms is not None:
            headers[DEADLINE_HEADER] = str(frame.deadline_ms)
        headers.update(self.settings.auth_headers())
        meta = frame.meta
        if meta and "latency" in meta:  # the robot's own latency parts, for the netapp's page
            headers[ROBOT_LATENCY_HEADER] = wire_json.dumps(meta["latency"])
        if meta:  # the frame's trace context: W3C headers on HTTP
            headers.update((k, meta[k]) for k in (TRACEPARENT, TRACESTATE) if k in meta)
        return headers


class FramePoster:
    """`POST /send_image?wait=true` on urllib3's connection pool itself: the per-frame path. requests adds about
    0.5 ms a request on top (it reads the environment, .netrc and cookies for every request); its settings for this
    URL (certificate bundle, proxy) are read once here, so a frame goes where `requests.post` would send it."""

    def __init__(self, url: str, settings: SessionSettings) -> None:
        verify, proxies = environment_settings(url)
        tls: dict[str, Any] = {}
        if url.startswith("https:"):
            tls = {"cert_reqs": "CERT_REQUIRED" if verify else "CERT_NONE"}
            if isinstance(verify, str):
                tls["ca_certs"] = verify
            elif verify:
                tls["ca_certs"] = requests.certs.where()
        proxy = requests.utils.select_proxy(url, proxies)
        pools = {"maxsize": settings.max_in_flight, **tls}
        self._http = urllib3.proxy_from_url(proxy, **pools) if proxy else urllib3.PoolManager(**pools)
        self._target = f"{url}/send_image?wait=true"
        timeout_s = settings.result_timeout_s
        self._timeout = urllib3.Timeout(connect=timeout_s, read=timeout_s)

    def post(self, data: bytes, headers: dict[str, str]) -> Answer:
        response = self._http.urlopen(
            "POST", self._target, body=data, headers=headers, timeout=self._timeout, retries=False, redirect=False
        )
        return Answer(response.status, response.headers, response.data)

    def close(self) -> None:
        self._http.clear()


class Answer:
    """A urllib3 answer read as `netapp.client.errors` reads a `requests.Response`."""

    def __init__(self, status: int, headers: Any, body: bytes) -> None:
        self.status_code, self.headers, self.content = status, headers, body

    @property
    def text(self) -> str:
        return self.content.decode("utf-8", "replace")

    def json(self) -> Any:
        return wire_json.loads(self.content)
