"""aiortc's video jitter buffer, releasing a picture at its last packet.

aiortc 1.16 hands a picture to its decoder only when the next picture's first packet arrives (`JitterBuffer.add`
looks for a change of timestamp and ignores the marker bit), so every picture waits one frame interval: 100 ms at
10 fps, on top of the network. The marker bit is set on a video picture's last packet (RFC 3551, RFC 7741, RFC 6184),
so a picture whose packets have all arrived in sequence, up to the one with the marker, is complete then.
"""

from __future__ import annotations

from typing import Any


def marker_jitter_buffer() -> type:
    """A `JitterBuffer` that also releases a picture at its marker bit (built when aiortc is importable)."""
    from aiortc.jitterbuffer import JitterBuffer, JitterFrame

    class MarkerJitterBuffer(JitterBuffer):
        def _remove_frame(self, sequence_number: int) -> Any:
            if self._is_video:
                frame = self._complete_frame()
                if frame is not None:
                    return frame
            return super()._remove_frame(sequence_number)

        def _complete_frame(self) -> Any:
            """The oldest picture, if every packet of it up to its marker is here (in sequence from the origin)."""
            packets: list[Any] = []
            for count in range(self.capacity):
                packet = self._packets[(self._origin + count) % self.capacity]
                if packet is None or (packets and packet.timestamp != packets[0].timestamp):
                    return None  # a gap, or a picture whose end never came: aiortc's own rule decides
                packets.append(packet)
                if packet.marker:
                    self.remove(count + 1)
                    return JitterFrame(data=b"".join(p._data for p in packets), timestamp=packet.timestamp)
            return None

    return MarkerJitterBuffer


def install() -> None:
    """Make aiortc's receivers (of this process) use it."""
    import aiortc.rtcrtpreceiver

    if getattr(aiortc.rtcrtpreceiver.JitterBuffer, "__name__", "") != "MarkerJitterBuffer":
        aiortc.rtcrtpreceiver.JitterBuffer = marker_jitter_buffer()
