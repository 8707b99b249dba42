"""The ASGI application: FastAPI (HTTP), python-socketio (5G-ERA Socket.IO) and the `frames` WebSocket on one port,
over one dataplane."""

from __future__ import annotations

import asyncio
import contextlib
import logging

from fastapi import FastAPI

from netapp import __version__, http_errors
from netapp.frame import H264
from netapp.protocol import H264_EVENT
from netapp.sdk.processor import Processor
from netapp.server.brokers.intake import BrokerIntake
from netapp.server.brokers.observer import ResultPublishers
from netapp.server.cluster.heartbeat import send_heartbeats
from netapp.server.cluster.replica import ReplicaApp
from netapp.server.commands import Commands
from netapp.server.dataplane import DataPlane
from netapp.server.decoding.h264 import H264Decoder
from netapp.server.frames.endpoint import FramesEndpoint
from netapp.server.http import errors as serving_errors
from netapp.server.http.routes import ROUTERS
from netapp.server.rtp.hub import RtpSessions
from netapp.server.services import NetAppServices
from netapp.server.settings import Settings
from netapp.server.sio.handlers import SocketIOHandlers
from netapp.server.sio.limits import BoundedAsyncServer, bounded_packet_class
from netapp.server.sources.hub import Sources
from netapp.server.ui.live import LiveView
from netapp.server.ui.routes import camera_router
from netapp.server.ui.routes import router as ui_router
from netapp.server.webrtc.peers import WebRtcPeers
from netapp.tracing import Tracer

log = logging.getLogger(__name__)


def create_app(processor: Processor, settings: Settings | None = None, tracer: Tracer | None = None) -> ReplicaApp:
    """Serve `processor`. The processor loads at start-up, off the event loop; /readyz answers 200 after.
    `drain()` on the app (SIGTERM, `netapp.server.runner`) moves its robots elsewhere before it stops.
    `tracer`: where sampled frames' spans go; None: as the OTel variables say (docs/tracing.md)."""
    settings = settings or Settings()
    services = NetAppServices.build(processor, settings, tracer)
    dataplane = DataPlane(services)
    live = LiveView()  # what the /ui pages show: told of every result by the dataplane
    dataplane.observe(live)
    publishers = ResultPublishers.build(settings.publish, processor, services.metrics.registry)  # `--publish`
    dataplane.observe(publishers)
    # Without PyAV it answers every frame with why.
    h264 = H264Decoder(settings.max_pixels, settings.h264_decode_share)
    sources = Sources(dataplane, settings)  # the cameras it pulls (`--source`), started once it is ready
    rtp = RtpSessions(dataplane, settings, h264)  # sessions whose H.264 comes over RTP (`--rtp-ports`)
    webrtc = WebRtcPeers(dataplane, settings)  # browsers' and robots' video tracks (`POST /webrtc/offer`)
    # The one command dispatch: Socket.IO's /control, the frames endpoint and HTTP's /register
    commands = Commands(dataplane, sources, rtp)
    # robots' frames from brokers' work queues (`--consume`), one more transport over the same dispatch
    intakes = [BrokerIntake(address, dataplane, settings, commands, h264) for address in settings.consume]

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        load = asyncio.create_task(services.pipeline.start())
        load.add_done_callback(_log_load_failure)
        tasks = [asyncio.create_task(_expire_idle_sessions(dataplane, settings.session_ttl_s))]
        publishers.start()  # each broker connects in its own task: one that is down delays nothing
        if settings.sources:
            tasks.append(asyncio.create_task(_start_sources(services.pipeline.ready, sources)))
        if intakes:
            tasks.append(asyncio.create_task(_start_intakes(services.pipeline.ready, intakes)))
        if settings.middleware_address:
            tasks.append(asyncio.create_task(send_heartbeats(services)))
        if settings.candidate:
            tasks.append(asyncio.create_task(_start_rollout(services)))
        try:
            yield
        finally:
            load.cancel()
            for task in tasks:
                task.cancel()
            await sources.stop()
            for intake in intakes:
                await intake.close()
            rtp.stop()
            await webrtc.stop()
            await services.pipeline.stop()
            await publishers.close()  # after the last results: what waits gets a moment to go
            if services.pipeline.tracing is not None:  # the last frames' spans, before the process goes
                services.pipeline.tracing.tracer.flush(1.0)
            await replica.forwarder.close()
            if services.revocations is not None:
                await services.revocations.close()

    # No /docs or /redoc: FastAPI would load them from a CDN, blank offline; /openapi.json stays.
    api = FastAPI(title="netapp", version=__version__, lifespan=lifespan, docs_url=None, redoc_url=None)
    api.state.netapp = services
    api.state.dataplane = dataplane
    api.state.settings = settings
    api.state.commands = commands
    api.state.live = live
    api.state.publishers = publishers
    api.state.intakes = intakes
    api.state.webrtc = webrtc
    http_errors.install(api)
    serving_errors.install(api)
    for router in ROUTERS:
        api.include_router(router)
    api.include_router(ui_router)
    api.include_router(camera_router)
    sio = BoundedAsyncServer(
        async_mode="asgi",
        cors_allowed_origins="*",
        max_http_buffer_size=settings.transport_limit_bytes,
        serializer=bounded_packet_class(settings.max_attachments, settings.transport_limit_bytes),
    )
    api.state.socketio = SocketIOHandlers(sio, dataplane, settings, commands)
    api.state.socketio.add_frame_event(H264_EVENT, "h264", H264, h264.open)
    api.state.frames = FramesEndpoint(dataplane, settings, commands, h264)
    replica = ReplicaApp(sio, api, services, api.state.frames)
    return replica


async def _start_intakes(ready: asyncio.Event, intakes: list[BrokerIntake]) -> None:
    """Consume the brokers' work queues once the model is loaded (their frames would only be refused before; they
    wait in the broker meanwhile)."""
    await ready.wait()
    for intake in intakes:
        intake.start()


async def _start_sources(ready: asyncio.Event, sources: Sources) -> None:
    """Pull the cameras once the model is loaded (their pictures would only be refused before)."""
    await ready.wait()
    await sources.start()


async def _start_rollout(services: NetAppServices) -> None:
    """`--candidate`: its shadow begins once the current model serves."""
    from netapp.server.rollout.rollout import RolloutRefused

    await services.pipeline.ready.wait()
    settings = services.settings
    assert settings.candidate is not None
    try:
        services.rollout.start(
            settings.candidate, settings.candidate_sha256, settings.rollout_policy, settings.shadowing
        )
    except RolloutRefused as exc:
        log.error("--candidate %s: %s", settings.candidate, exc)


def _log_load_failure(task: asyncio.Task) -> None:
    if not task.cancelled() and task.exception() is not None:
        log.error("the processor failed to load: %s", task.exception())


async def _expire_idle_sessions(dataplane: DataPlane, ttl_s: float) -> None:
    """HTTP robots that vanish without /unregister must not hold memory forever."""
    period = max(1.0, ttl_s / 4)
    while True:
        await asyncio.sleep(period)
        dataplane.expire_idle()
