"""The cameras on the event loop: each one a session of the pipeline (fair turns with the robots, newest wins), its
results told to its subscribers.

A camera's reading thread (`reader`) offers each decoded picture; only the newest waits here (one slot per camera),
and one hand-off at a time is scheduled on the loop, so a camera faster than the loop never queues anything. The
hand-off submits the picture like a robot's frame (`DataPlane.submit`, labelled `rtsp`): counted, queued newest-wins,
decoded to BGR on the lane that runs it, and its result comes back here (the result sink), to go to the camera's
subscribers (`netapp watch`: a `frames` or Socket.IO connection that sent WATCH; docs/cameras.md#results), a few
per address, a watcher that reads nothing let go (`watchers`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from netapp.protocol import ELSEWHERE_REASON, POD_NAME_ENV, SOURCE_FIELD
from netapp.server.connection import Connection, Tell
from netapp.server.dataplane import DataPlane, IncomingFrame
from netapp.server.decoding.h264 import to_bgr
from netapp.server.errors import FrameError, FrameRejected, RequestRefused, ServingError, refusal_fields
from netapp.server.sessions import Session
from netapp.server.settings import Settings, SourceSpec
from netapp.server.sources import relay as relays
from netapp.server.sources.lease_api import LeaseClient, lease_login
from netapp.server.sources.leases import CameraLeases
from netapp.server.sources.metrics import SourceMetrics
from netapp.server.sources.reader import CameraReader
from netapp.server.sources.results_file import ResultsFiles
from netapp.server.sources.watchers import STALL_S, STALLED, Watcher, refusal, tell_all

log = logging.getLogger(__name__)

LABEL = "rtsp"  # the `transport` label of the cameras' frames and sessions
SESSION_PREFIX = "camera:"
# A subscriber (`Tell`): sends one result (a result message with `source` in it) without waiting; its transport bounds
# what waits for a subscriber that does not read (`FramesWire.tell`, the Socket.IO handlers' watchers).


@dataclass(eq=False)
class Camera:
    """A camera's own part of its session's `Connection` (its `wire`, `netapp.server.connection`): what it pulls,
    its reader, its subscribers and the newest picture waiting."""

    spec: SourceSpec
    session: Session
    reader: CameraReader | None = None
    subscribers: dict[Tell, Watcher] = field(default_factory=dict)
    relay: asyncio.Task | None = None  # its results from the replica that pulls it (relay.py), while watched here
    relay_token: str | None = None  # the token of the watcher that started the relay: the holder checks it too
    _slot: tuple[Any, int, int] | None = None  # (picture, its packet's bytes, when decoded: ns), the newest only
    _lock: threading.Lock = field(default_factory=threading.Lock)


class Sources:
    """Every `--source` camera of one app. `start()` and `stop()` run in the app's lifespan."""

    def __init__(self, dataplane: DataPlane, settings: Settings) -> None:
        self.dataplane = dataplane
        self.settings = settings
        self.specs = settings.sources
        self.metrics = SourceMetrics(dataplane.registry)
        self.cameras: dict[str, Camera] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._tasks: set[asyncio.Task] = set()
        # With --camera-leases: who holds which camera (`leases`), and the readers of cameras let go, still ending
        self._leases: CameraLeases | None = None
        self._lease_task: asyncio.Task | None = None
        self._kube: LeaseClient | None = None
        self._me = ""  # this replica's identity in the Leases
        self._stopping: list[CameraReader] = []
        folder = settings.source_results
        self.files = None if folder is None else ResultsFiles(folder, settings.source_results_bytes)
        if self.specs:  # the robots' transports are present at 0 from the start; so is this one where it is used
            dataplane.show_transport(LABEL)

    async def start(self) -> None:
        """Open each camera's session and start its reader (it connects on its own, and again when lost)."""
        self._loop = asyncio.get_running_loop()
        settings = self.settings
        for spec in self.specs:
            connection = Connection(SESSION_PREFIX + spec.name, LABEL, self)
            try:
                session = self.dataplane.open_session(
                    LABEL, spec.name, {}, session_id=connection.key, connection=connection
                )
            except ServingError as exc:  # more cameras than --max-sessions
                log.error("camera %s: not pulled: %s", spec.name, exc)
                continue
            camera = connection.wire = Camera(spec, session)
            self.metrics.add(spec.name)
            self.cameras[spec.name] = camera
            if settings.camera_leases is None:
                self._pull(camera)
        if settings.camera_leases is not None and self.cameras:
            self._leases = await self._lease_cameras(settings.camera_leases)

    def _pull(self, camera: Camera) -> None:
        """Start the camera's reader (a new one each time its Lease is won)."""
        settings, spec = self.settings, camera.spec
        camera.reader = CameraReader(
            spec, self._offerer(camera), self.metrics, settings.max_pixels, settings.max_payload_bytes
        )
        log.info("camera %s: pulling %s (transport %s)", spec.name, spec.shown_url, spec.transport)
        camera.reader.start()

    def _let_go(self, camera: Camera) -> None:
        """Stop the camera's reader (its Lease was lost); its thread ends on its own, within its read timeout."""
        if camera.reader is not None:
            log.info("camera %s: another replica pulls it now", camera.spec.name)
            camera.reader.stop()
            self._stopping = [r for r in self._stopping if r.alive] + [camera.reader]
            camera.reader = None

    async def _lease_cameras(self, namespace: str) -> CameraLeases | None:
        """Pull only the cameras whose Lease this replica holds (docs/cameras.md#several-replicas)."""
        try:  # the pod's service account; $KUBECONFIG where it is set (read now, not at import)
            login = lease_login()
        except ValueError as exc:
            log.error("%s; pulling no camera", exc)
            return None
        settings = self.settings
        self._me = settings.advertise_url or os.environ.get(POD_NAME_ENV) or f"{socket.gethostname()}-{os.getpid()}"
        self._kube = LeaseClient(login)

        def changed(name: str, held: bool) -> None:
            camera = self.cameras.get(name)
            if camera is not None and held:
                self._stop_relay(camera)  # its watchers here get this replica's own results from now on
                self._pull(camera)
            elif camera is not None:
                self._let_go(camera)
                if camera.subscribers:
                    self._start_relay(camera)

        leases = CameraLeases(self._kube, namespace, settings.netapp_name or "netapp", self._me, changed)
        self._lease_task = asyncio.create_task(leases.run(list(self.cameras)), name="netapp-camera-leases")
        return leases

    async def stop(self) -> None:
        """Stop every reader and wait for its thread (FFmpeg's sockets close with it); give the Leases back; close
        the sessions."""
        if self._lease_task is not None:
            self._lease_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._lease_task
        for camera in self.cameras.values():
            await relays.stop(camera.relay)
            camera.relay = None
        readers = [c.reader for c in self.cameras.values() if c.reader is not None] + self._stopping
        for reader in readers:
            reader.stop()
        if self._leases is not None:
            await self._leases.release()
        if self._kube is not None:
            await self._kube.close()
        for reader in readers:
            if not await asyncio.to_thread(reader.join):
                log.warning("camera %s: its reader did not end in time", reader.spec.name)
        for task in list(self._tasks):
            task.cancel()
        for camera in self.cameras.values():
            self.dataplane.close_session(camera.session, "the netapp is shutting down")
            camera.subscribers.clear()
        self.cameras.clear()
        if self.files is not None:
            self.files.close()

    # -- pictures: reading thread -> loop -> pipeline ----------------------------------------------------------------

    def _offerer(self, camera: Camera) -> Callable[[Any, int], None]:
        loop = self._loop
        assert loop is not None

        def offer(picture: Any, size_bytes: int) -> None:  # on the camera's thread
            with camera._lock:
                waiting = camera._slot is not None
                camera._slot = (picture, size_bytes, time.time_ns())
            if not waiting:
                try:
                    loop.call_soon_threadsafe(self._hand_off, camera)
                except RuntimeError:  # the loop is closing: the reader is being stopped
                    pass

        return offer

    def _hand_off(self, camera: Camera) -> None:
        with camera._lock:
            slot, camera._slot = camera._slot, None
        if slot is None or camera.session.closed:
            return
        task = asyncio.ensure_future(self._submit(camera, *slot))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _submit(self, camera: Camera, picture: Any, size_bytes: int, timestamp: int) -> None:
        async def parse() -> IncomingFrame:  # the camera's edge: its reader decoded the picture
            return IncomingFrame.picture(timestamp, lambda: to_bgr(picture), size_bytes)

        try:
            await self.dataplane.submit(camera.session, LABEL, parse, sink=self)
        except FrameRejected as exc:  # counted by the dataplane (e.g. the model still loading)
            log.debug("camera %s: a picture was refused: %s", camera.spec.name, exc)

    # -- the result sink --------------------------------------------------------------------------------------------

    async def result(self, session: Session, message: dict[str, Any]) -> None:
        camera = self.camera_of(session.id)
        if camera is None:
            return
        message = {**message, SOURCE_FIELD: camera.spec.name}
        if self.files is not None:
            self.files.write(camera.spec.name, message)
            self.metrics.results_written.labels(source=camera.spec.name).inc()
        self._tell(camera, message)

    def _tell(self, camera: Camera, message: dict[str, Any]) -> None:
        for tell in tell_all(camera.subscribers, message, time.monotonic()):
            host = camera.subscribers.pop(tell).host
            self.metrics.watchers_refused.labels(reason=STALLED).inc()
            self.metrics.subscribers.labels(source=camera.spec.name).set(len(camera.subscribers))
            log.warning("camera %s: a watcher at %s read nothing for %.0f s: let go", camera.spec.name, host, STALL_S)

    async def error(self, session: Session, timestamp: int | None, error: FrameError) -> None:
        """A picture that became no result: counted by the pipeline already (superseded ones above all)."""

    # -- subscribers ------------------------------------------------------------------------------------------------

    def subscribe(
        self, name: Any, tell: Tell, token: str | None = None, forwarded: bool = False, client: str = ""
    ) -> str:
        """`tell` gets each result of camera `name` from now on, relayed from the replica that pulls it where that is
        another one (`token`: the watcher's, which the relay shows the holder); its acknowledgement's message, or
        RequestRefused (an unknown camera, too many subscribers on it or from the address `client`, a camera pulled
        elsewhere that cannot be relayed: nobody holds it yet, or the WATCH is itself a relay's)."""
        camera = self.cameras.get(name) if isinstance(name, str) else None
        relayed = camera is not None and self._leases is not None and camera.reader is None
        if relayed and (forwarded or self._holder_url(camera) is None):
            message = f"camera {name} is pulled by another replica: watch it through the Service again"
            raise RequestRefused(ELSEWHERE_REASON, message, 503, retry_after_s=1)
        if camera is None:
            known = ", ".join(sorted(self.cameras)) or "none"
            raise RequestRefused("unknown_source", f"no camera {str(name)[:80]!r} here: this netapp pulls {known}", 404)
        if tell not in camera.subscribers:
            everyone = [w for c in self.cameras.values() for w in c.subscribers.values()]
            refused = refusal(name, camera.subscribers, everyone, client)
            if refused is not None:
                self.metrics.watchers_refused.labels(reason=refused.reason).inc()
                raise refused
            camera.subscribers[tell] = Watcher(client, forwarded, time.monotonic())
            self.metrics.subscribers.labels(source=name).set(len(camera.subscribers))
        if token and camera.relay_token is None:  # kept for a relay started later, when the camera goes elsewhere
            camera.relay_token = token
        if relayed:
            if camera.relay is None:
                self._start_relay(camera)
            return f"watching camera {name} (relayed from {self._holder_url(camera)}, which pulls it)"
        state = "up" if camera.reader is not None and camera.reader.outage.up else "down, reconnecting"
        return f"watching camera {name} (now {state})"

    def unsubscribe(self, tell: Tell) -> None:
        """`tell`'s connection went away."""
        for name, camera in self.cameras.items():
            if tell in camera.subscribers:
                del camera.subscribers[tell]
                self.metrics.subscribers.labels(source=name).set(len(camera.subscribers))
                if not camera.subscribers:
                    self._stop_relay(camera)

    # -- relays: a camera another replica pulls, watched here ------------------------------------------------------

    def _holder_url(self, camera: Camera) -> str | None:
        holders = self._leases.holders if self._leases is not None else {}
        return relays.holder_url(holders.get(camera.spec.name), self._me)

    def _start_relay(self, camera: Camera) -> None:
        name = camera.spec.name
        relay = relays.Relay(
            name,
            lambda: self._holder_url(camera),
            lambda message: self._tell(camera, message),
            camera.relay_token,
            self.dataplane.peer_ssl,
            lambda outcome: self.metrics.relays.labels(source=name, outcome=outcome).inc(),
        )
        camera.relay = asyncio.create_task(relay.run(), name=f"netapp-camera-relay-{name}")

    @staticmethod
    def _stop_relay(camera: Camera) -> None:
        if camera.relay is not None:
            camera.relay.cancel()  # its connection closes as the task ends
            camera.relay = None

    def camera_of(self, session_id: str) -> Camera | None:
        """The camera whose session this is, while it is open."""
        connection = self.dataplane.connection(session_id)
        return connection.wire if connection is not None and connection.transport == LABEL else None


def watch_answer(
    sources: Sources | None,
    command: dict[str, Any],
    tell: Tell,
    token: str | None = None,
    forwarded: bool = False,
    client: str = "",
) -> tuple[bool, str, dict[str, Any]]:
    """WATCH on a transport, whether or not its app pulls cameras (`sources` None: none); `token`, `forwarded` and
    `client`: the connection's (`Sources.subscribe`)."""
    if sources is None or not sources.cameras:
        return False, "this netapp pulls no camera (netapp serve --source NAME=rtsp://...)", {"reason": "no_sources"}
    data = command.get("data")
    try:
        name = data.get(SOURCE_FIELD) if isinstance(data, dict) else None
        return True, sources.subscribe(name, tell, token, forwarded, client), {}
    except ServingError as exc:
        return False, str(exc), refusal_fields(exc)
