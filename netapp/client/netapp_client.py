"""NetAppClient: send frames to one or several netapps (over HTTP, Socket.IO as 5G-ERA, `frames`, RTP), get results
by callback or iterator, with a deadline, a policy over the netapps and a local fallback.

The client is a facade: its parts, one idea each, are wired in `netapp.client.assembly.ClientParts` (the links and
their transports, the ledger, the sender, the switcher and policy, the receiver and delivery, the checkpoints, the
fallback, the uplink adapter, the traces; `docs/design.md`, the data path), and its moves are `netapp.client.moves`.
Every result says where it came from (`source`: the netapp's URL, or `local`), whether it was late, and its latency
split into uplink, queue, inference and downlink (`breakdown`, `netapp.client.timing`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import requests

from netapp.client.adapt import Choice
from netapp.client.assembly import ClientParts, open_carrier
from netapp.client.delivery import Result
from netapp.client.encoders import Frame
from netapp.client.errors import NetAppError, NetAppRefused
from netapp.client.hints import Hint
from netapp.client.link import RECONNECT_INTERVAL_S
from netapp.client.moves import Moves
from netapp.client.options import ClientOptions
from netapp.client.send_settings import SendSettings
from netapp.client.switching import Switch
from netapp.client.transports import Transport, TransportCallbacks, bearer_headers

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from netapp.client.options import ClientKeywords

__all__ = ["NetAppClient", "NetAppError", "NetAppRefused", "Result", "Switch"]

log = logging.getLogger(__name__)


class NetAppClient:
    """A robot's connection to one or several netapps. Thread-safe `send()`; use as a context manager.

    Keyword arguments (grouped in `netapp.client.options`): `transport` http | ws | frames | rtp (or h264, the
    shorthand for ws with the h264 codec), `codec` jpeg | h264; session: args, robot_id, token, connect_timeout_s,
    result_timeout_s, checkpoint_every, websocket_first; sending: max_in_flight, jpeg_quality, h264_options, pacing,
    full_frames; service: deadline_ms, policy, fallback, tracer (docs/tracing.md); callbacks: on_result, on_error,
    on_switch; the uplink: adapt (off | auto), latency_budget_ms, accuracy_floor, accuracy_profile."""

    def __init__(self, url: str | Sequence[str], transport: str = "ws", **keywords: Unpack[ClientKeywords]) -> None:
        urls = [url] if isinstance(url, str) else list(url)
        if not urls:
            raise ValueError("give at least one netapp URL")
        self.options = ClientOptions.from_keywords(transport, **keywords)
        self._parts = parts = ClientParts(urls, self.options, self._open_session, self._apply_choice)
        self.stats, self.policy, self._links = parts.stats, parts.policy, parts.links
        self._moves = Moves(parts, self.options.session.result_timeout_s)
        parts.switcher.on_retire = self._moves.retire

    def _apply_choice(self, choice: Choice) -> None:
        """The adapter's choice for the next frames (the frame rate it keeps itself, in `send`)."""
        self.set_send_settings(
            long_side=choice.long_side,
            jpeg_quality=choice.jpeg_quality,
            bitrate_kbps=choice.bitrate_kbps,
            codec=choice.codec,
            fps=choice.fps,
        )

    def _open_session(self, url: str, callbacks: TransportCallbacks) -> Transport:
        return open_carrier(self.options, url, callbacks)  # the options now: a new token serves the next sessions

    # -- what it is ------------------------------------------------------------------------------------------------

    @property
    def transport(self) -> str:
        """What carries the frames: http, ws, frames or rtp."""
        return self.options.sending.transport

    @property
    def codec(self) -> str:
        """How frames are encoded: jpeg or h264."""
        return self.options.sending.codec

    @property
    def args(self) -> dict[str, Any]:
        return self.options.session.args

    @property
    def robot_id(self) -> str | None:
        return self.options.session.robot_id

    @property
    def token(self) -> str | None:
        """The netapps' bearer token; a new one (a switchover's NetApp has its own) serves the next sessions."""
        return self.options.session.token

    @token.setter
    def token(self, token: str | None) -> None:
        self.options = replace(self.options, session=replace(self.options.session, token=token))

    @property
    def max_in_flight(self) -> int:
        return self.options.sending.max_in_flight

    @property
    def deadline_ms(self) -> float | None:
        return self.options.service.deadline_ms

    @property
    def on_result(self) -> Callable[[Result], None] | None:
        return self._parts.delivery.on_result

    @on_result.setter
    def on_result(self, callback: Callable[[Result], None] | None) -> None:
        self._parts.delivery.on_result = callback

    @property
    def on_error(self) -> Callable[[dict[str, Any]], None] | None:
        return self._parts.delivery.on_error

    @on_error.setter
    def on_error(self, callback: Callable[[dict[str, Any]], None] | None) -> None:
        self._parts.delivery.on_error = callback

    @property
    def on_switch(self) -> Callable[[Switch], None] | None:
        return self._parts.switcher.on_switch

    @on_switch.setter
    def on_switch(self, callback: Callable[[Switch], None] | None) -> None:
        self._parts.switcher.on_switch = callback

    # -- its state -------------------------------------------------------------------------------------------------

    @property
    def urls(self) -> tuple[str, ...]:
        return tuple(link.url for link in self._links)

    @property
    def url(self) -> str:
        """The netapp in use: the first one frames go to (else the first given)."""
        mode = self._parts.switcher.mode
        return self._links[mode.netapps[0]].url if mode.netapps else self._links[0].url

    @property
    def link_state(self) -> str:
        """What the client does with the netapps: connected, hedging, fallback or reconnecting."""
        return self._parts.switcher.mode.state

    @property
    def session_state(self) -> Any:
        """The latest session state a stateful netapp sent (`checkpoint_every`), or None. A new session (after
        `switch_url()`, a reconnect or a failover) gets it back with SET_STATE before its first frame, so a tracker
        there continues with the same track ids."""
        return self._parts.checkpoints.latest

    state = session_state  # the older name

    @property
    def connected(self) -> bool:
        return any(link.connected for link in self._links)

    @property
    def session_id(self) -> str | None:
        """The first netapp's id of this robot's session (None before connecting)."""
        return self._links[0].session_id

    # -- lifecycle -------------------------------------------------------------------------------------------------

    def connect(self) -> NetAppClient:
        """Open a session with every netapp; raises NetAppError when none can be reached and there is no fallback.
        A netapp that cannot be reached now is tried again in the background."""
        if self._parts.fallback is not None:
            try:
                self._parts.fallback.start()
            except Exception as exc:  # a model that does not load: say so before anything is sent
                raise NetAppError(f"cannot load the local fallback: {exc}") from exc
        failures = []
        # One netapp: a refusal with a Retry-After is tried again within the connect budget. Several: the next one
        # serves meanwhile, and the refusing one is tried again in the background.
        retry_within_s = self.options.session.connect_timeout_s if len(self._links) == 1 else 0.0
        for link in self._links:
            try:
                link.open(retry_within_s)
            except NetAppError as exc:
                failures.append(exc)
                reason = exc.reason if isinstance(exc, NetAppRefused) else "unreachable"
                self._parts.receiver.outage(link, f"{exc}; trying again every {RECONNECT_INTERVAL_S:g} s", reason)
                link.reconnect_in_background()
        if len(failures) == len(self._links) and self._parts.fallback is None:
            self.close()
            raise failures[0] if len(failures) == 1 else NetAppError("; ".join(str(f) for f in failures))
        self._parts.sender.start()
        self._parts.switcher.start("connected")
        return self

    def close(self) -> None:
        if not self._parts.ledger.close():  # closed already
            return
        self._parts.sender.join()
        for link in self._links:
            link.close()
        with self._parts.wire.between_frames():
            for link in self._links:
                link.encoder.close()
        if self._parts.fallback is not None:
            self._parts.fallback.close()
        if self._parts.traces is not None:  # the last frames' spans, before the robot moves on
            self._parts.traces.tracer.flush(1.0)

    def __enter__(self) -> NetAppClient:
        return self.connect()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def switch_url(self, url: str) -> None:
        """Move the netapp in use to another URL, break before make: its frames in flight are counted lost."""
        self._moves.switch_url(url)

    def move_to(self, url: str) -> None:
        """Move the netapp in use to another URL, make before break (a switchover the middleware asks for): a
        session opens there first (a stateful netapp's state restored in it), every frame goes to both until the
        new one has answered on time a few times in a row (`netapp.client.policy`, moves), then the old one is
        closed once none of its frames is still in flight. No frame is lost to the move."""
        self._moves.move_to(url)

    def processor_info(self, timeout_s: float = 2.0) -> dict[str, Any] | None:
        """What the netapp in use serves (its `/v2` metadata's model: name, platform, ...), None if it does not
        say."""
        try:
            response = requests.get(f"{self.url}/v2", headers=bearer_headers(self.token), timeout=timeout_s)
            models = response.json().get("models") if response.ok else None
        except (requests.RequestException, ValueError, AttributeError):
            return None
        return models[0] if isinstance(models, list) and models and isinstance(models[0], dict) else None

    @property
    def input_sizes(self) -> dict[str, tuple[int, int] | None]:
        """What each netapp's processor consumes (width, height), as it said (None: it did not say)."""
        return {link.url: link.input_size for link in self._links}

    @property
    def hints(self) -> dict[str, Hint | None]:
        """The latest valid hint of each netapp's results (`docs/client.md#hints`), None before one."""
        return {link.url: link.hint for link in self._links}

    # -- frames and results ----------------------------------------------------------------------------------------

    @property
    def send_settings(self) -> SendSettings:
        """What the next frame goes on the wire with (`docs/client.md#what-is-sent`)."""
        return self._parts.sender.settings

    def set_send_settings(self, settings: SendSettings | None = None, **changes: Any) -> SendSettings:
        """Change what the next frames are sent with: a whole `SendSettings`, or some of its fields by name
        (`long_side`, `jpeg_quality`, `bitrate_kbps`, `codec`, `fps`); ValueError for a value out of range. The netapp's
        processor size stays an upper bound (unless `full_frames`). Returns the settings now in force."""
        unknown = set(changes) - {f.name for f in fields(SendSettings)}
        if unknown:
            raise TypeError(f"unknown send settings {sorted(unknown)}")
        self._parts.sender.settings = replace(settings or self._parts.sender.settings, **changes)
        return self._parts.sender.settings

    def send(self, frame: Frame, timestamp: int | None = None) -> int:
        """Queue a frame (BGR array, or JPEG bytes for jpeg); returns its timestamp, the key of its result. Never
        waits for the network: the newest frame waits for a free slot, an older waiting one is dropped. With
        `adapt="auto"` a frame beyond the chosen frame rate is not sent (`adapt_report()["skipped_for_rate"]`)."""
        adapter = self._parts.adapter
        if adapter is not None:
            if isinstance(frame, np.ndarray):  # JPEG bytes go as they are: nothing to choose
                fits = None if self.options.sending.full_frames else self._links[0].input_size
                adapter.begin((frame.shape[1], frame.shape[0]), fits, self._links[0].accuracy_profile)
            if not adapter.admit():
                return timestamp if timestamp is not None else time.time_ns()
        return self._parts.sender.send(frame, timestamp)

    def adapt_report(self) -> dict[str, Any] | None:
        """With `adapt="auto"`: the budget, the floor, the settings now, their changes over time and the share of
        results within the budget (`netapp.client.adapt.adapter.UplinkAdapter.report`); None when off."""
        return None if self._parts.adapter is None else self._parts.adapter.report()

    def transport_report(self) -> dict[str, Any]:
        """Each netapp's transport counters, by URL, for the transports that keep some (`rtp`: packets, NACKs,
        PLIs, results by path)."""
        carriers = [(link.url, link.carrier) for link in self._links]
        return {url: carrier.report() for url, carrier in carriers if hasattr(carrier, "report")}

    def results(self, timeout: float | None = None) -> Iterator[Result]:
        """Results as they arrive; stops after `timeout` seconds without one (None: until closed)."""
        return self._parts.delivery.results(timeout, self._parts.closed)

    def wait_idle(self, timeout_s: float = 10.0) -> bool:
        """Wait until nothing is pending or in flight (e.g. before reading the last results)."""
        return self._parts.sender.wait_idle(timeout_s)
