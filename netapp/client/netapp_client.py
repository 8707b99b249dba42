"""NetAppClient: send frames to one or several netapps over HTTP or Socket.IO (5G-ERA), get results by callback or
iterator, with a deadline, a policy over the netapps and a local fallback.

The client is a facade over parts with one idea each (`docs/design.md`, the robot client):

* `options`: the keyword arguments, grouped (session, sending, service, callbacks); `codec` beside `transport`.
* `link.NetAppLink`, one per netapp: its session (a transport from `netapp.client.transports`), its frame encoder
  (`netapp.client.encoders`), its pacer (`netapp.client.pacing`), its clock estimate, reconnects and moves.
* `ledger.Ledger`: the newest frame waiting for a slot and the frames in flight (claim, settle, lose, expire).
* `wire.WireSequencer`: frames go on the wire in the order their slots were claimed (H.264 never goes back).
* `sender.FrameSender`: `send()` never waits for the network; the sender thread sends the newest waiting frame.
* `switching.Switcher`: the `Policy` (`netapp.client.policy`: primary, hedge, adaptive) and the local fallback
  (`netapp.client.fallback`): what the client does, `on_switch`, the newest frame handed to the fallback.
* `adapt.UplinkAdapter` (with `adapt="auto"`): what the uplink carries chooses each frame's size and quality (or
  H.264 bitrate) and the frame rate, within a latency budget and above an accuracy floor (`netapp.client.adapt`).
* `receiver.Receiver`: what comes back from links and the fallback; `delivery`: the first answer wins, by callback
  or bounded queue, and the latest checkpoint of a stateful netapp is restored in each new session.

Every result says where it came from (`source`: the netapp's URL, or `local`), whether it was late, and its latency
split into uplink, queue, inference and downlink (`breakdown`, `netapp.client.timing`).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import requests

from netapp.client.adapt import AdaptConfig, Choice
from netapp.client.adapt.adapter import UplinkAdapter, profile_named
from netapp.client.delivery import Checkpoints, Result, ResultDelivery
from netapp.client.encoders import Frame, H264StreamEncoder, JpegEncoder
from netapp.client.errors import NetAppError, NetAppRefused
from netapp.client.fallback import LocalFallback
from netapp.client.hints import Hint, HintReader
from netapp.client.ledger import Ledger
from netapp.client.link import RECONNECT_INTERVAL_S, NetAppLink
from netapp.client.options import ClientOptions
from netapp.client.pacing import Pacer
from netapp.client.policy import Policy
from netapp.client.receiver import Receiver
from netapp.client.send_settings import SendSettings
from netapp.client.sender import FrameSender
from netapp.client.stats import ClientStats
from netapp.client.switching import Switch, Switcher
from netapp.client.tracing import SERVICE_NAME, FrameTraces
from netapp.client.transports import SessionSettings, Transport, TransportCallbacks, bearer_headers
from netapp.client.transports.frames import FramesTransport
from netapp.client.transports.http import HttpTransport
from netapp.client.transports.rtp import RtpTransport
from netapp.client.transports.socketio import SocketIOTransport
from netapp.client.urls import http_url
from netapp.client.wire import WireSequencer
from netapp.tracing import tracer_from_env

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from netapp.client.options import ClientKeywords

__all__ = ["NetAppClient", "NetAppError", "NetAppRefused", "Result", "Switch"]

log = logging.getLogger(__name__)

CARRIERS: dict[str, Callable[[str, SessionSettings, TransportCallbacks], Transport]] = {
    "http": HttpTransport,
    "ws": SocketIOTransport,
    "frames": FramesTransport,
    "rtp": RtpTransport,
}


class NetAppClient:
    """A robot's connection to one or several netapps. Thread-safe `send()`; use as a context manager.

    Keyword arguments (grouped in `netapp.client.options`): `transport` http | ws | frames (or h264, the shorthand
    for ws with the h264 codec), `codec` jpeg | h264; session: args, robot_id, token, connect_timeout_s,
    result_timeout_s, checkpoint_every, websocket_first; sending: max_in_flight, jpeg_quality, h264_options, pacing,
    full_frames; service: deadline_ms, policy, fallback, tracer (docs/tracing.md); callbacks: on_result, on_error,
    on_switch; the uplink: adapt (off | auto), latency_budget_ms, accuracy_floor, accuracy_profile."""

    def __init__(self, url: str | Sequence[str], transport: str = "ws", **keywords: Unpack[ClientKeywords]) -> None:
        urls = [url] if isinstance(url, str) else list(url)
        if not urls:
            raise ValueError("give at least one netapp URL")
        options = ClientOptions.from_keywords(transport, **keywords)
        self.options = options
        self.stats = ClientStats()
        self.policy = Policy(options.service.policy, len(urls), fallback=options.service.fallback is not None)
        self._closed = threading.Event()
        self._wire = WireSequencer()
        self._ledger = Ledger(self.stats, self._wire.ticket, self._closed)
        self._checkpoints = Checkpoints(self.stats)
        self._delivery = ResultDelivery(self.stats, options.callbacks.on_result, options.callbacks.on_error)
        fallback = options.service.fallback
        self._fallback = (
            None if fallback is None else LocalFallback(fallback, self._local_result, self._local_error, self.args)
        )
        self._switcher = Switcher(
            self.policy,
            lambda: self.urls,
            self._ledger,
            self._fallback,
            self.deadline_ms,
            self.stats,
            options.callbacks.on_switch,
        )
        self._links: list[NetAppLink] = []
        self._adapter = self._uplink_adapter()
        tracer = options.service.tracer or tracer_from_env(SERVICE_NAME)
        self._traces = FrameTraces(tracer, self.transport) if tracer is not None else None
        self._receiver = Receiver(
            self._links,
            self._ledger,
            self._switcher,
            self._delivery,
            self._checkpoints,
            self.stats,
            self.deadline_ms,
            options.sending.pacing,
            self._closed,
            self._adapter,
            self._traces,
        )
        self._jpeg = JpegEncoder()  # stateless: one encoding serves every netapp
        self._hints = HintReader(self.stats)
        for i, u in enumerate(urls):
            self._links.append(self._new_link(i, u))
        self._switcher.on_retire = self._retire
        self._sender = FrameSender(
            self._links,
            self._ledger,
            self._wire,
            self._switcher,
            self._fallback,
            self.stats,
            self.deadline_ms,
            options.session.result_timeout_s,
            self._closed,
            SendSettings(jpeg_quality=options.sending.jpeg_quality),
            options.sending.full_frames,
            None if self._adapter is None else self._adapter.sent,
            self._traces,
        )

    def _uplink_adapter(self) -> UplinkAdapter | None:
        adapt = self.options.adapt
        if adapt.mode != "auto":
            return None
        config = AdaptConfig(adapt.latency_budget_ms, adapt.accuracy_floor, codec=self.codec)
        return UplinkAdapter(profile_named(adapt.profile), config, self._apply_choice)

    def _apply_choice(self, choice: Choice) -> None:
        """The adapter's choice for the next frames (the frame rate it keeps itself, in `send`)."""
        self.set_send_settings(
            long_side=choice.long_side, jpeg_quality=choice.jpeg_quality, bitrate_kbps=choice.bitrate_kbps
        )

    def _new_link(self, index: int, url: str) -> NetAppLink:
        # H.264: a stream per netapp, each decodes its own
        encoder = H264StreamEncoder(self.options.sending.h264_options) if self.codec == "h264" else self._jpeg
        pacer = Pacer(self.max_in_flight)
        return NetAppLink(
            index,
            http_url(url),
            encoder,
            pacer,
            self._open_session,
            self._receiver,
            self._wire,
            self._closed,
            self._hints,
        )

    def _open_session(self, url: str, callbacks: TransportCallbacks) -> Transport:
        session, sending = self.options.session, self.options.sending
        settings = SessionSettings(
            robot_id=session.robot_id,
            args=dict(session.args),
            max_in_flight=sending.max_in_flight,
            connect_timeout_s=session.connect_timeout_s,
            result_timeout_s=session.result_timeout_s,
            token=session.token,
            websocket_first=session.websocket_first,
        )
        return CARRIERS[sending.transport](url, settings, callbacks)

    def _local_result(self, message: dict[str, Any]) -> None:
        self._receiver.local_result(message)

    def _local_error(self, message: dict[str, Any]) -> None:
        self._receiver.local_error(message)

    # -- what it is ------------------------------------------------------------------------------------------------

    @property
    def transport(self) -> str:
        """What carries the frames: http, ws or frames."""
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
        return self._delivery.on_result

    @on_result.setter
    def on_result(self, callback: Callable[[Result], None] | None) -> None:
        self._delivery.on_result = callback

    @property
    def on_error(self) -> Callable[[dict[str, Any]], None] | None:
        return self._delivery.on_error

    @on_error.setter
    def on_error(self, callback: Callable[[dict[str, Any]], None] | None) -> None:
        self._delivery.on_error = callback

    @property
    def on_switch(self) -> Callable[[Switch], None] | None:
        return self._switcher.on_switch

    @on_switch.setter
    def on_switch(self, callback: Callable[[Switch], None] | None) -> None:
        self._switcher.on_switch = callback

    # -- its state -------------------------------------------------------------------------------------------------

    @property
    def urls(self) -> tuple[str, ...]:
        return tuple(link.url for link in self._links)

    @property
    def url(self) -> str:
        """The netapp in use: the first one frames go to (else the first given)."""
        mode = self._switcher.mode
        return self._links[mode.netapps[0]].url if mode.netapps else self._links[0].url

    @property
    def link_state(self) -> str:
        """What the client does with the netapps: connected, hedging, fallback or reconnecting."""
        return self._switcher.mode.state

    @property
    def session_state(self) -> Any:
        """The latest session state a stateful netapp sent (`checkpoint_every`), or None. A new session (after
        `switch_url()`, a reconnect or a failover) gets it back with SET_STATE before its first frame, so a tracker
        there continues with the same track ids."""
        return self._checkpoints.latest

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
        if self._fallback is not None:
            try:
                self._fallback.start()
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
                self._receiver.outage(link, f"{exc}; trying again every {RECONNECT_INTERVAL_S:g} s", reason)
                link.reconnect_in_background()
        if len(failures) == len(self._links) and self._fallback is None:
            self.close()
            raise failures[0] if len(failures) == 1 else NetAppError("; ".join(str(f) for f in failures))
        self._sender.start()
        self._switcher.start("connected")
        return self

    def close(self) -> None:
        if not self._ledger.close():  # closed already
            return
        self._sender.join()
        for link in self._links:
            link.close()
        with self._wire.between_frames():
            for link in self._links:
                link.encoder.close()
        if self._fallback is not None:
            self._fallback.close()
        if self._traces is not None:  # the last frames' spans, before the robot moves on
            self._traces.tracer.flush(1.0)

    def __enter__(self) -> NetAppClient:
        return self.connect()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def switch_url(self, url: str) -> None:
        """Move the netapp in use to another URL, break before make: its frames in flight are counted lost."""
        url = http_url(url)
        link = self._links[self._in_use()]
        if url != link.url:
            link.switch(url)

    def move_to(self, url: str) -> None:
        """Move the netapp in use to another URL, make before break (a switchover the middleware asks for): a
        session opens there first (a stateful netapp's state restored in it), every frame goes to both until the
        new one has answered on time a few times in a row (`netapp.client.policy`, moves), then the old one is
        closed once none of its frames is still in flight. No frame is lost to the move."""
        url = http_url(url)
        old = self._in_use()
        if any(link.url == url for i, link in enumerate(self._links) if not self.policy.health[i].retired):
            return  # there already (or moving there)
        # A netapp a previous move left behind is closed by now: its place takes the new one (at most one spare).
        spare = next((i for i, h in enumerate(self.policy.health) if h.retired and not h.up), None)
        now = time.monotonic_ns()
        if spare is None:
            link = self._new_link(len(self._links), url)
            self._links.append(link)
            self._switcher.add()
            self._switcher.begin_move(old, link.index, now)
        else:
            link = self._links[spare]
            self._switcher.begin_move(old, spare, now)
        log.info("moving %s -> %s (make before break)", self._links[old].url, url)
        try:
            if spare is None:
                link.open()
            else:
                link.switch(url)
        except NetAppError as exc:  # the old one serves on; the move ends by its timeout
            self._receiver.outage(link, f"{exc}; trying again every {RECONNECT_INTERVAL_S:g} s", "unreachable")
            link.reconnect_in_background()
            return
        if self._ledger.wait_idle(0.0):  # no frame on its way: nothing to hedge, the old one may go now
            self._switcher.finish_move(f"moved to {url}")

    def _in_use(self) -> int:
        mode = self._switcher.mode
        return mode.netapps[0] if mode.netapps else self.policy.first

    def _retire(self, index: int) -> None:
        """A move left this netapp behind: close it once its frames in flight are answered (or lost)."""

        def close() -> None:
            self._ledger.wait_clear(index, self.options.session.result_timeout_s)
            self._links[index].close()

        threading.Thread(target=close, name="netapp-retire", daemon=True).start()

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
        return self._sender.settings

    def set_send_settings(self, settings: SendSettings | None = None, **changes: Any) -> SendSettings:
        """Change what the next frames are sent with: a whole `SendSettings`, or some of its fields by name
        (`long_side`, `jpeg_quality`, `bitrate_kbps`); ValueError for a value out of range. The netapp's processor
        size stays an upper bound (unless `full_frames`). Returns the settings now in force."""
        unknown = set(changes) - {f.name for f in fields(SendSettings)}
        if unknown:
            raise TypeError(f"unknown send settings {sorted(unknown)}")
        self._sender.settings = replace(settings or self._sender.settings, **changes)
        return self._sender.settings

    def send(self, frame: Frame, timestamp: int | None = None) -> int:
        """Queue a frame (BGR array, or JPEG bytes for jpeg); returns its timestamp, the key of its result. Never
        waits for the network: the newest frame waits for a free slot, an older waiting one is dropped. With
        `adapt="auto"` a frame beyond the chosen frame rate is not sent (`adapt_report()["skipped_for_rate"]`)."""
        adapter = self._adapter
        if adapter is not None:
            if isinstance(frame, np.ndarray):  # JPEG bytes go as they are: nothing to choose
                fits = None if self.options.sending.full_frames else self._links[0].input_size
                adapter.begin((frame.shape[1], frame.shape[0]), fits, self._links[0].accuracy_profile)
            if not adapter.admit():
                return timestamp if timestamp is not None else time.time_ns()
        return self._sender.send(frame, timestamp)

    def adapt_report(self) -> dict[str, Any] | None:
        """With `adapt="auto"`: the budget, the floor, the settings now, their changes over time and the share of
        results within the budget (`netapp.client.adapt.adapter.UplinkAdapter.report`); None when off."""
        return None if self._adapter is None else self._adapter.report()

    def transport_report(self) -> dict[str, Any]:
        """Each netapp's transport counters, by URL, for the transports that keep some (`rtp`: packets, NACKs,
        PLIs, results by path)."""
        carriers = [(link.url, link.carrier) for link in self._links]
        return {url: carrier.report() for url, carrier in carriers if hasattr(carrier, "report")}

    def results(self, timeout: float | None = None) -> Iterator[Result]:
        """Results as they arrive; stops after `timeout` seconds without one (None: until closed)."""
        return self._delivery.results(timeout, self._closed)

    def wait_idle(self, timeout_s: float = 10.0) -> bool:
        """Wait until nothing is pending or in flight (e.g. before reading the last results)."""
        return self._sender.wait_idle(timeout_s)
