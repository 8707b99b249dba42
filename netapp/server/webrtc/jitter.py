"""aiortc's video jitter buffer, releasing a picture at its last packet.

aiortc 1.16 hands a picture to its decoder only when the next picture's first packet arrives (`JitterBuffer.add`
looks for a change of timestamp and ignores the marker bit), so every picture waits one frame interval: 100 ms at
10 fps, on top of the network. The marker bit is set on a video picture's last packet (RFC 3551, RFC 7741, RFC 6184),
so a picture whose packets have all arrived in sequence, up to the one with the marker, is complete then.

It also keeps damaged pictures from the decoder, and so from the model. When aiortc gives up on a gap (its buffer
full behind a packet never sent again) it drops pictures and asks for a keyframe (PLI); the pictures after them
refer to what was dropped, and the decoder would conceal the damage rather than refuse them. Here every picture is
held back (counted: `on_skipped`) until a keyframe arrives, and the keyframe asked for again every KEYFRAME_EVERY.

aiortc's receiver asks for a lost packet again at the measured round trip here (`netapp.server.webrtc.nacks`, up to
three times); a gap all those asks leave open would keep aiortc waiting until its buffer is full behind it (512
packets: a second or more of 720p video). Here a gap still open GIVE_UP_S after later packets came is given up at
once, in the same way: skipped, a keyframe asked for, pictures held till it.

And it keeps a picture larger than `--max-pixels` from the decoder: the size its keyframe claims (the H.264 SPS, the
VP8 key frame header) is read before aiortc's decoder sees it, so a peer sending 7680x4320 costs no 8K decoding.
Such a keyframe, and the pictures after it until a keyframe within the bound, are held back; the peer's wiring is
told (`on_too_large`) and refuses it as every transport does (`too_many_pixels`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from netapp.server.decoding.h264_bitstream import sps_sizes

GIVE_UP_S = 0.25  # a packet still missing after this is lost (its asks: three timeouts of about a round trip each)

KEYFRAME_EVERY = 10  # pictures held back between two keyframe requests (1 s at 10 fps)
VP8_START_CODE = b"\x9d\x01\x2a"  # bytes 3 to 5 of a VP8 key frame (RFC 6386 9.1)
H264_KEY_NALS = (5, 7)  # an IDR slice, or an SPS (which a keyframe starts with)


def is_keyframe(data: bytes) -> bool:
    """Whether a depayloaded picture (aiortc's: VP8 frame, or H.264 in Annex B) decodes on its own."""
    if data.startswith(
        (b"\x00\x00\x01", b"\x00\x00\x00\x01")
    ):  # H.264: a VP8 frame's first byte has its key or show bit set
        return any(data[i + 3] & 0x1F in H264_KEY_NALS for i in _start_codes(data))
    return len(data) >= 6 and not data[0] & 1 and data[3:6] == VP8_START_CODE


def claimed_size(data: bytes) -> tuple[int, int] | None:
    """The size (width, height) a depayloaded picture's header claims: its largest H.264 SPS, or its VP8 key frame
    header; None where it carries neither. ValueError for an SPS that cannot be read."""
    if data.startswith((b"\x00\x00\x01", b"\x00\x00\x00\x01")):
        return max(sps_sizes(data), key=lambda size: size[0] * size[1], default=None)
    if len(data) >= 10 and not data[0] & 1 and data[3:6] == VP8_START_CODE:  # 14 bits each, 2 of scaling
        return int.from_bytes(data[6:8], "little") & 0x3FFF, int.from_bytes(data[8:10], "little") & 0x3FFF
    return None


def _start_codes(data: bytes) -> list[int]:
    """Where each 00 00 01 is (the NAL unit's header follows it)."""
    found, at = [], data.find(b"\x00\x00\x01")
    while 0 <= at < len(data) - 3:
        found.append(at)
        at = data.find(b"\x00\x00\x01", at + 3)
    return found


def marker_jitter_buffer() -> type:
    """A `JitterBuffer` that also releases a picture at its marker bit (built when aiortc is importable)."""
    from aiortc.jitterbuffer import JitterBuffer, JitterFrame

    class MarkerJitterBuffer(JitterBuffer):
        on_skipped: Callable[[], None] | None = None  # told of each picture held back for want of a keyframe
        on_keyframe: Callable[[], None] | None = None  # told of each keyframe released to the decoder
        # this receiver's peer's bound (`bound`): told (width, height, timestamp) of a keyframe over it, held back
        max_pixels: int | None = None
        on_too_large: Callable[[int, int, int], None] | None = None
        _waiting_keyframe = False
        _held = 0

        _gap_since: float | None = None  # when the packet at the origin was first found missing, others behind it

        def add(self, packet: Any) -> tuple[bool, Any]:
            asked, frame = super().add(packet)
            if not self._is_video:
                return asked, frame
            if frame is None:
                asked = self._give_up_gap(time.monotonic()) or asked
            if asked:  # aiortc dropped pictures (and asked for a keyframe): what follows may refer to them
                self._waiting_keyframe, self._held = True, 0
            if frame is None:
                return asked, frame
            if self._over_the_bound(frame):
                self._waiting_keyframe, self._held = True, 0
                return asked, None
            keyframe = is_keyframe(frame.data)
            if keyframe and MarkerJitterBuffer.on_keyframe is not None:
                MarkerJitterBuffer.on_keyframe()
            if not self._waiting_keyframe:
                return asked, frame
            if keyframe:
                self._waiting_keyframe = False
                return asked, frame
            self._held += 1
            if MarkerJitterBuffer.on_skipped is not None:
                MarkerJitterBuffer.on_skipped()
            return asked or self._held % KEYFRAME_EVERY == 0, None

        def bound(self, max_pixels: int, on_too_large: Callable[[int, int, int], None]) -> None:
            """Hold back pictures claiming more than `max_pixels`, telling `on_too_large` of each."""
            self.max_pixels, self.on_too_large = max_pixels, on_too_large

        def _over_the_bound(self, frame: Any) -> bool:
            """Whether this picture's header claims more than `max_pixels` (an unreadable SPS: it does)."""
            if self.max_pixels is None:
                return False
            try:
                size = claimed_size(frame.data)
            except ValueError:
                size = (self.max_pixels + 1, 1)
            if size is None or size[0] * size[1] <= self.max_pixels:
                return False
            if self.on_too_large is not None:
                self.on_too_large(size[0], size[1], frame.timestamp)
            return True

        def _give_up_gap(self, now: float) -> bool:
            """Skip the missing packets at the origin once they have been missing GIVE_UP_S; whether it did."""
            if self._origin is None or self._packets[self._origin % self.capacity] is not None:
                self._gap_since = None
                return False
            if self._gap_since is None:
                self._gap_since = now
                return False
            if now - self._gap_since < GIVE_UP_S:
                return False
            skipped = 0
            while self._packets[self._origin % self.capacity] is None and skipped < self.capacity:
                self.remove(1)
                skipped += 1
            self._gap_since = None
            self._waiting_keyframe, self._held = True, 0
            return True

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


def install(on_skipped: Callable[[], None] | None = None, on_keyframe: Callable[[], None] | None = None) -> None:
    """Make aiortc's receivers (of this process) use it; `on_skipped` counts the pictures held back, `on_keyframe`
    the keyframes decoded (each one a sender's encoder restarted, or a PLI answered)."""
    import aiortc.rtcrtpreceiver

    if getattr(aiortc.rtcrtpreceiver.JitterBuffer, "__name__", "") != "MarkerJitterBuffer":
        aiortc.rtcrtpreceiver.JitterBuffer = marker_jitter_buffer()
    aiortc.rtcrtpreceiver.JitterBuffer.on_skipped = on_skipped
    aiortc.rtcrtpreceiver.JitterBuffer.on_keyframe = on_keyframe
