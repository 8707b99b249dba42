"""Server settings: one dataclass, filled from the command line or by code."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Settings:
    max_payload_bytes: int = 8 * 1024 * 1024  # one frame; larger gets 413 / data_error
    queue_size: int = 1  # frames waiting per session; newest wins, older ones are dropped and counted
    results_buffer: int = 100  # results kept for HTTP polling per session; older ones are dropped and counted
    session_ttl_s: float = 300.0  # an HTTP session idle this long is closed
    wait_timeout_s: float = 30.0  # longest `POST /send_image?wait=true` waits for its result
    prepare_threads: int = 2  # decode + preprocess pool, beside the inference thread
    max_batch: int = 0  # frames from different robots per inference; 0: what the processor allows

    @property
    def transport_limit_bytes(self) -> int:
        """Largest Socket.IO message the transport reads. Past the frame limit but below this, the robot gets a
        data_error naming the limit; past this, the connection is closed (WebSocket 1009), bounding memory."""
        return 2 * self.max_payload_bytes + 64 * 1024
