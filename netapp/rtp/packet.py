"""RTP packets (RFC 3550 5.1) read and written, and the one RTCP packet the netapp sends (PLI, RFC 4585 6.3.1).

Every datagram is hostile: `parse` checks the version, and that the CSRC list, the header extension and the padding
all fit in the datagram, before any payload byte is used; it raises RtpError naming what is wrong (its `reason` is
the label the netapp counts it under).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

RTP_VERSION = 2
HEADER_BYTES = 12
MAX_DATAGRAM_BYTES = 1500  # an Ethernet MTU: a sender's packetiser keeps below it; larger datagrams are refused
DEFAULT_PAYLOAD_TYPE = 96  # the first dynamic payload type, what rtph264pay uses by default
H264_CLOCK_HZ = 90_000  # RTP timestamps of video (RFC 6184 8.2.1)
RTCP_PSFB = 206  # payload-specific feedback
PLI_FMT = 1


class RtpError(ValueError):
    """A datagram that is not RTP the netapp can use; `reason` is its metric label."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class RtpPacket:
    marker: bool
    payload_type: int
    sequence: int
    timestamp: int
    ssrc: int
    payload: bytes


def parse(datagram: bytes) -> RtpPacket:
    """A datagram -> its RTP packet; RtpError if malformed (see the module)."""
    size = len(datagram)
    if size > MAX_DATAGRAM_BYTES:
        raise RtpError("too_large", f"RTP datagram of {size} bytes is over {MAX_DATAGRAM_BYTES}")
    if size < HEADER_BYTES:
        raise RtpError("malformed", f"RTP datagram of {size} bytes is shorter than its {HEADER_BYTES}-byte header")
    first, second, sequence, timestamp, ssrc = struct.unpack_from("!BBHII", datagram)
    if first >> 6 != RTP_VERSION:
        raise RtpError("malformed", f"RTP version {first >> 6}, expected {RTP_VERSION}")
    start = HEADER_BYTES + 4 * (first & 0x0F)  # the CSRC list
    if first & 0x10:  # a header extension: 4 bytes, then its length in 32-bit words
        if start + 4 > size:
            raise RtpError("malformed", "RTP header extension truncated")
        start += 4 + 4 * struct.unpack_from("!H", datagram, start + 2)[0]
    end = size
    if first & 0x20:  # padding: its count is the last byte
        pad = datagram[-1]
        if pad == 0:
            raise RtpError("malformed", "RTP padding count of 0")
        end -= pad
    if start > end:
        raise RtpError("malformed", "RTP header (CSRCs, extension, padding) longer than the datagram")
    return RtpPacket(bool(second & 0x80), second & 0x7F, sequence, timestamp, ssrc, bytes(datagram[start:end]))


def build(payload: bytes, *, payload_type: int, sequence: int, timestamp: int, ssrc: int, marker: bool) -> bytes:
    """One RTP packet, without CSRCs, extension or padding."""
    second = (0x80 if marker else 0) | (payload_type & 0x7F)
    header = struct.pack("!BBHII", RTP_VERSION << 6, second, sequence & 0xFFFF, timestamp & 0xFFFFFFFF, ssrc)
    return header + payload


def pli(sender_ssrc: int, media_ssrc: int) -> bytes:
    """An RTCP Picture Loss Indication: "send a keyframe" (RFC 4585 6.3.1)."""
    return struct.pack("!BBHII", (RTP_VERSION << 6) | PLI_FMT, RTCP_PSFB, 2, sender_ssrc, media_ssrc)


def is_pli(datagram: bytes) -> bool:
    """Whether a datagram is an RTCP PLI (`pli`)."""
    return len(datagram) >= 12 and datagram[0] == (RTP_VERSION << 6) | PLI_FMT and datagram[1] == RTCP_PSFB


def is_rtcp(datagram: bytes) -> bool:
    """Whether a datagram on a muxed port is RTCP (RFC 5761 4: packet types 192..223 where RTP's marker+PT is)."""
    return len(datagram) >= 2 and 192 <= datagram[1] <= 223


def sequence_after(previous: int, sequence: int) -> int:
    """How far `sequence` is after `previous`, modulo 2^16, in -32768..32767 (1: the next one)."""
    return ((sequence - previous + 0x8000) & 0xFFFF) - 0x8000


def unwrap_timestamp(previous: int | None, timestamp: int) -> int:
    """A 32-bit RTP timestamp unwrapped past its wrap: the value nearest `previous` (the last one unwrapped) that
    equals `timestamp` modulo 2^32; `timestamp` itself for the first."""
    if previous is None:
        return timestamp
    return previous + ((timestamp - previous + (1 << 31)) & 0xFFFFFFFF) - (1 << 31)


RTCP_RTPFB = 205  # transport-layer feedback
NACK_FMT = 1  # generic NACK (RFC 4585 6.2.1)
MAX_NACK_ENTRIES = 64  # (PID, BLP) pairs read from one NACK: up to 1,088 packets


def nack(sender_ssrc: int, media_ssrc: int, sequences: list[int]) -> bytes:
    """An RTCP generic NACK asking for `sequences` again (each PID with a bitmask of the 16 after it)."""
    fci = b""
    ordered = sorted(set(sequences), key=lambda s: sequence_after(sequences[0], s))
    i = 0
    while i < len(ordered):
        pid, blp, j = ordered[i], 0, i + 1
        while j < len(ordered) and 0 < sequence_after(pid, ordered[j]) <= 16:
            blp |= 1 << (sequence_after(pid, ordered[j]) - 1)
            j += 1
        fci += struct.pack("!HH", pid, blp)
        i = j
    first = (RTP_VERSION << 6) | NACK_FMT
    return struct.pack("!BBHII", first, RTCP_RTPFB, 2 + len(fci) // 4, sender_ssrc, media_ssrc) + fci


def parse_nack(datagram: bytes) -> list[int]:
    """The sequence numbers a generic NACK asks for (bounded: MAX_NACK_ENTRIES pairs); [] for anything else."""
    if len(datagram) < 16 or datagram[0] >> 6 != RTP_VERSION or datagram[1] != RTCP_RTPFB:
        return []
    if datagram[0] & 0x1F != NACK_FMT:
        return []
    words = struct.unpack_from("!H", datagram, 2)[0]
    end = min(len(datagram), 4 * (words + 1), 12 + 4 * MAX_NACK_ENTRIES)
    sequences = []
    for at in range(12, end - 3, 4):
        pid, blp = struct.unpack_from("!HH", datagram, at)
        sequences.append(pid)
        sequences += [(pid + k + 1) & 0xFFFF for k in range(16) if blp >> k & 1]
    return sequences


RTCP_APP = 204  # application-defined (RFC 3550 6.7)
RESULT_APP = b"NRES"  # the name of the APP packets that carry a result back to an RTP sender that asked (`results`)
APP_HEADER_BYTES = 12  # V/P/subtype, PT, length, SSRC, the 4-byte name
MAX_APP_DATA_BYTES = MAX_DATAGRAM_BYTES - 28 - APP_HEADER_BYTES  # one unfragmented datagram: IPv4 and UDP headers


def app(sender_ssrc: int, name: bytes, data: bytes, pad: bytes = b" ") -> bytes:
    """An RTCP APP packet carrying `data`, padded with `pad` to 32-bit words (JSON takes trailing spaces)."""
    if len(name) != 4 or len(data) > MAX_APP_DATA_BYTES:
        raise ValueError(f"an APP packet has a 4-byte name and at most {MAX_APP_DATA_BYTES} bytes of data")
    data += pad * (-len(data) % 4)
    words = (APP_HEADER_BYTES + len(data)) // 4 - 1
    return struct.pack("!BBHI4s", RTP_VERSION << 6, RTCP_APP, words, sender_ssrc, name) + data


def parse_app(datagram: bytes, name: bytes) -> tuple[int, bytes] | None:
    """(sender SSRC, data) of an RTCP APP packet named `name`, None for anything else (or a malformed one)."""
    if not APP_HEADER_BYTES <= len(datagram) <= MAX_DATAGRAM_BYTES or datagram[1] != RTCP_APP:
        return None
    if datagram[0] >> 6 != RTP_VERSION:
        return None
    words, ssrc, got = struct.unpack_from("!HI4s", datagram, 2)
    if got != name or 4 * (words + 1) != len(datagram):
        return None
    return ssrc, bytes(datagram[APP_HEADER_BYTES:])
