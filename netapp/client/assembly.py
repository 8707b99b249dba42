"""The robot client's parts, wired once (`NetAppClient` is the facade over them; docs/design.md, the data path).

`ClientParts` builds the thirteen parts in the order they need each other, from the client's options: the stats,
the policy and its `Switcher`, the `Ledger` and the `WireSequencer`, a `NetAppLink` per netapp (each with its
encoder, `Pacer` and transport, made by `open_carrier`), the `Receiver` and `ResultDelivery`, the `FrameSender`,
the session `Checkpoints`, the local fallback, the uplink adapter and the frame traces.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from typing import Any

from netapp.client import h264
from netapp.client.adapt import AdaptConfig, Choice
from netapp.client.adapt.adapter import UplinkAdapter, profile_named
from netapp.client.delivery import Checkpoints, ResultDelivery
from netapp.client.encoders import FrameEncoder, H264StreamEncoder, JpegEncoder, SwitchingEncoder
from netapp.client.fallback import LocalFallback
from netapp.client.hints import HintReader
from netapp.client.ledger import Ledger
from netapp.client.link import NetAppLink, OpenSession
from netapp.client.options import ClientOptions
from netapp.client.pacing import Pacer
from netapp.client.policy import Policy
from netapp.client.receiver import Receiver
from netapp.client.send_settings import SendSettings
from netapp.client.sender import FrameSender
from netapp.client.stats import ClientStats
from netapp.client.switching import Switcher
from netapp.client.tracing import SERVICE_NAME, FrameTraces
from netapp.client.transports import SessionSettings, Transport, TransportCallbacks
from netapp.client.transports.frames import FramesTransport
from netapp.client.transports.http import HttpTransport
from netapp.client.transports.rtp import RtpTransport
from netapp.client.transports.socketio import SocketIOTransport
from netapp.client.urls import is_broker_url, netapp_url
from netapp.client.wire import WireSequencer
from netapp.frame import H264, JPEG
from netapp.tracing import tracer_from_env

CODEC_SWITCHING = ("ws", "frames")  # the carriers that take JPEG and H.264 frames in one session

CARRIERS: dict[str, Callable[[str, SessionSettings, TransportCallbacks], Transport]] = {
    "http": HttpTransport,
    "ws": SocketIOTransport,
    "frames": FramesTransport,
    "rtp": RtpTransport,
}


def open_carrier(options: ClientOptions, url: str, callbacks: TransportCallbacks) -> Transport:
    """A transport to `url` (not connected yet) with the session options in force now: a new token serves the next
    sessions."""
    session, sending = options.session, options.sending
    settings = SessionSettings(
        robot_id=session.robot_id,
        args=dict(session.args),
        max_in_flight=sending.max_in_flight,
        connect_timeout_s=session.connect_timeout_s,
        result_timeout_s=session.result_timeout_s,
        token=session.token,
        websocket_first=session.websocket_first,
    )
    if is_broker_url(url):  # the URL names a broker: its frames go through it, whatever carries the others
        from netapp.client.transports.broker import BrokerTransport  # the broker extra's clients, only when used

        return BrokerTransport(url, settings, callbacks)
    return CARRIERS[sending.transport](url, settings, callbacks)


def uplink_adapter(options: ClientOptions, apply: Callable[[Choice], None]) -> UplinkAdapter | None:
    """With `adapt="auto"`, the adapter whose choices `apply` puts in force; None when the uplink does not adapt."""
    adapt = options.adapt
    if adapt.mode == "off":
        return None
    config = AdaptConfig(
        adapt.latency_budget_ms,
        adapt.accuracy_floor,
        codec=options.sending.codec,
        switch_codec=switches_codec(options),
    )
    return UplinkAdapter(profile_named(adapt.profile), config, apply)


def switches_codec(options: ClientOptions) -> bool:
    """Whether the adapter may choose H.264 below JPEG frame by frame: `adapt="auto"`, JPEG on a transport that
    carries both (Socket.IO, `frames`), and PyAV to encode it."""
    sending = options.sending
    if options.adapt.mode != "auto" or sending.codec != JPEG or sending.transport not in CODEC_SWITCHING:
        return False
    try:
        h264.require_av()
    except ImportError:
        return False
    return True


class ClientParts:
    """Every part of one client, wired: built once, each part told only of the parts it works with."""

    def __init__(
        self,
        urls: Sequence[str],
        options: ClientOptions,
        open_session: OpenSession,
        apply_choice: Callable[[Choice], None],
    ) -> None:
        session, sending, service = options.session, options.sending, options.service
        self._sending = sending  # what never changes (a new token does: `open_session` reads the client's)
        self.stats = ClientStats()
        self.policy = Policy(service.policy, len(urls), fallback=service.fallback is not None)
        self.closed = threading.Event()
        self.wire = WireSequencer()
        self.ledger = Ledger(self.stats, self.wire.ticket, self.closed)
        self.checkpoints = Checkpoints(self.stats)
        self.delivery = ResultDelivery(self.stats, options.callbacks.on_result, options.callbacks.on_error)
        fallback = service.fallback
        self.fallback = (
            None if fallback is None else LocalFallback(fallback, self._local_result, self._local_error, session.args)
        )
        self.links: list[NetAppLink] = []
        self.switcher = Switcher(
            self.policy,
            lambda: tuple(link.url for link in self.links),
            self.ledger,
            self.fallback,
            service.deadline_ms,
            self.stats,
            options.callbacks.on_switch,
        )
        self.adapter = uplink_adapter(options, apply_choice)
        self._switch_codec = self.adapter is not None and self.adapter.config.switch_codec
        tracer = service.tracer or tracer_from_env(SERVICE_NAME)
        self.traces = FrameTraces(tracer, sending.transport) if tracer is not None else None
        self.receiver = Receiver(
            self.links,
            self.ledger,
            self.switcher,
            self.delivery,
            self.checkpoints,
            self.stats,
            service.deadline_ms,
            sending.pacing,
            self.closed,
            self.adapter,
            self.traces,
        )
        self._jpeg = JpegEncoder()  # stateless: one encoding serves every netapp
        self._hints = HintReader(self.stats)
        self._open_session = open_session
        self.links.extend(self.new_link(i, url) for i, url in enumerate(urls))
        self.sender = FrameSender(
            self.links,
            self.ledger,
            self.wire,
            self.switcher,
            self.fallback,
            self.stats,
            service.deadline_ms,
            session.result_timeout_s,
            self.closed,
            SendSettings(jpeg_quality=sending.jpeg_quality),
            sending.full_frames,
            None if self.adapter is None else self.adapter.sent,
            self.traces,
            None if self.adapter is None else self.adapter.in_flight_cap,
        )

    def _local_result(self, message: dict[str, Any]) -> None:
        self.receiver.local_result(message)

    def _local_error(self, message: dict[str, Any]) -> None:
        self.receiver.local_error(message)

    def encoder(self) -> FrameEncoder:
        """A new link's encoder: H.264 a stream per netapp (each decodes its own), JPEG one for all."""
        sending = self._sending
        if sending.codec == H264:
            return H264StreamEncoder(sending.h264_options)
        return SwitchingEncoder(self._jpeg, sending.h264_options) if self._switch_codec else self._jpeg

    def new_link(self, index: int, url: str) -> NetAppLink:
        """The link to netapp `index` at `url` (not opened yet)."""
        pacer = Pacer(self._sending.max_in_flight)
        return NetAppLink(
            index,
            netapp_url(url),
            self.encoder(),
            pacer,
            self._open_session,
            self.receiver,
            self.wire,
            self.closed,
            self._hints,
        )
