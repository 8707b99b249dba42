"""An H.264 access unit (Annex B) -> RTP payloads (RFC 6184, packetisation mode 1): each NAL unit alone when it
fits, else FU-A fragments. What the robot client sends; the netapp's `depacketize` reads it."""

from __future__ import annotations

from collections.abc import Iterator

from netapp.rtp.depacketize import FU_A

MAX_PAYLOAD_BYTES = 1400  # an RTP payload: with IP, UDP and RTP headers, under a 1500-byte MTU


def split_annex_b(data: bytes) -> list[bytes]:
    """The NAL units of an Annex B byte stream (start codes of 3 or 4 bytes removed)."""
    nals: list[bytes] = []
    starts: list[tuple[int, int]] = []  # (where the start code begins, where its NAL unit begins)
    i = data.find(b"\x00\x00\x01")
    while i >= 0:
        begin = i - 1 if i > 0 and data[i - 1] == 0 else i
        starts.append((begin, i + 3))
        i = data.find(b"\x00\x00\x01", i + 3)
    for k, (_, start) in enumerate(starts):
        end = starts[k + 1][0] if k + 1 < len(starts) else len(data)
        if start < end:
            nals.append(data[start:end])
    return nals


def payloads(access_unit: bytes, max_payload: int = MAX_PAYLOAD_BYTES) -> Iterator[bytes]:
    """The RTP payloads of one access unit, in order (the last one gets the marker bit)."""
    for nal in split_annex_b(access_unit):
        if len(nal) <= max_payload:
            yield nal
            continue
        indicator = (nal[0] & 0xE0) | FU_A
        kind = nal[0] & 0x1F
        body = nal[1:]
        room = max_payload - 2
        for at in range(0, len(body), room):
            start = 0x80 if at == 0 else 0
            end = 0x40 if at + room >= len(body) else 0
            yield bytes([indicator, start | end | kind]) + body[at : at + room]
