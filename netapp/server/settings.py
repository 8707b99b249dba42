"""Server settings: one dataclass, filled from the command line or by code."""

from __future__ import annotations

import os
from dataclasses import dataclass, field


def default_prepare_threads() -> int:
    """Decoding beside inference pays only with spare cores: where onnxruntime already uses every core (CPU
    inference on two), a decode thread preempts one of its workers and the whole inference waits for it, so
    decoding then runs on the inference thread itself (measured: bench/README.md)."""
    return 0 if (os.cpu_count() or 1) <= 2 else 2


@dataclass
class Settings:
    max_payload_bytes: int = 8 * 1024 * 1024  # one frame; larger gets 413 / data_error
    queue_size: int = 1  # frames waiting per session; newest wins, older ones are dropped and counted
    results_buffer: int = 100  # results kept for HTTP polling per session; older ones are dropped and counted
    session_ttl_s: float = 300.0  # an HTTP session idle this long is closed
    wait_timeout_s: float = 30.0  # longest `POST /send_image?wait=true` waits for its result
    # decode + preprocess threads beside the inference thread; 0: on the inference thread, before each batch
    prepare_threads: int = field(default_factory=default_prepare_threads)
    max_batch: int = 0  # frames from different robots per inference; 0: what the processor allows
    # capacity (netapp.server.capacity): the hard limit leaves each robot this share of its input rate; 0: no limit
    hard_share: float = 0.5
    assumed_robot_fps: float = 10.0  # a robot's input rate until robots stream (the published limits use it)
    # the 5G-ERA heartbeat: POST {middleware_address}/status/netapp every second (5G-ERA injects these as env vars)
    middleware_address: str | None = None
    netapp_id: str | None = None
    netapp_name: str | None = None

    @property
    def transport_limit_bytes(self) -> int:
        """Largest Socket.IO message the transport reads. Past the frame limit but below this, the robot gets a
        data_error naming the limit; past this, the connection is closed (WebSocket 1009), bounding memory."""
        return 2 * self.max_payload_bytes + 64 * 1024
