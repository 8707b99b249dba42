"""How a frame read off a `frames` binary message (on the WebSocket, or from a broker's work queue) goes to its
connection's decoder: bounded by `--max-payload`, then JPEG's decoder (one for all: a JPEG stands alone) or the
connection's own H.264 stream."""

from __future__ import annotations

from collections.abc import Callable

from netapp.frame import JPEG, EncodedFrame
from netapp.server.connection import Connection
from netapp.server.dataplane import IncomingFrame
from netapp.server.decoding.decoder import FrameDecoder
from netapp.server.decoding.h264 import H264Decoder
from netapp.server.decoding.jpeg import JpegDecoder
from netapp.server.errors import FrameRejected
from netapp.server.settings import Settings


class FrameDecoding:
    def __init__(self, settings: Settings, h264: H264Decoder) -> None:
        self.limit = settings.max_payload_bytes
        self.jpeg = JpegDecoder(settings.max_pixels)
        self.h264 = h264

    def incoming(self, connection: Connection, frame: EncodedFrame) -> IncomingFrame:
        """`frame`, bounded, with its decoding (not yet run); FrameRejected for one over the limit."""
        if frame.size > self.limit:
            raise FrameRejected("payload_too_large", f"frame of {frame.size} bytes is over {self.limit}")
        decoder = connection.decoder(frame.codec, self._opener(frame.codec))
        return IncomingFrame(frame, decoder.frame(frame), in_order=decoder.in_order)

    def _opener(self, codec: str) -> Callable[[], FrameDecoder]:
        """How a connection opens its decoder for `codec`: JPEG frames stand alone (one decoder for all), H.264
        gets a stream of its own."""
        return (lambda: self.jpeg) if codec == JPEG else self.h264.open
