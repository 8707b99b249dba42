"""Hostile RTP for the tests and bench/hostile.py: malformed datagrams, a wrong payload type, a stranger's flood,
absurd `rtp` arguments. Each is dropped (or refused) and counted by the netapp under the reason given here."""

from __future__ import annotations

import socket
import struct
import time

from netapp.rtp.packet import build

ABSURD_RTP_ARGS = (  # each refused with `bad_rtp`, the session never opened
    {"address": "1" * 1_000_000},
    {"payload_type": list(range(100_000))},
    {"payload_type": 5},
    {"sdp": "v=0\r\n" * 100_000},
    "m=video 9 RTP/AVP 96",
)


def malformed(ssrc: int, payload_type: int = 96, base: int = 0) -> list[bytes]:
    """Datagrams the gate or the depacketiser refuses as `malformed` (or `too_large`), with the right SSRC; the
    last four follow a packet of sequence number `base` (a gap would hide what is wrong with them)."""
    header = struct.pack("!BBHII", 0x80, payload_type, 7, 1, ssrc)

    def rtp(payload: bytes, sequence: int) -> bytes:
        return build(payload, payload_type=payload_type, sequence=sequence, timestamp=sequence, ssrc=ssrc, marker=True)

    return [
        b"\x80" * 11,  # shorter than a header
        struct.pack("!BBHII", 0x40, payload_type, 1, 1, ssrc) + b"\x65",  # version 1
        struct.pack("!BBHII", 0x8F, payload_type, 1, 1, ssrc),  # 15 CSRCs, none there
        struct.pack("!BBHII", 0x90, payload_type, 1, 1, ssrc) + struct.pack("!HH", 0xBEDE, 0xFFFF),  # extension
        struct.pack("!BBHII", 0xA0, payload_type, 1, 1, ssrc) + b"\x65\xff",  # padding past the header
        header + b"\x00" * 1500,  # over an MTU
        rtp(b"\x78\x00", base + 1),  # STAP-A with a size cut short
        rtp(b"\x78" + struct.pack("!H", 60000) + b"\x65", base + 2),  # STAP-A with a size past the packet
        rtp(b"\x7c\x05\x88", base + 3),  # FU-A middle without its start
        rtp(b"\x79\x65", base + 4),  # STAP-B (interleaved mode)
    ]


def send_all(datagrams: list[bytes], target: tuple[str, int], sock: socket.socket | None = None) -> int:
    """Send each datagram (from `sock`, else a new socket); how many were sent."""
    own = sock is None
    sock = sock or socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for datagram in datagrams:
            sock.sendto(datagram, target)
    finally:
        if own:
            sock.close()
    return len(datagrams)


def flood(target: tuple[str, int], seconds: float, ssrc: int = 0, size: int = 1400) -> int:
    """A stranger's flood: well-formed RTP datagrams of `size` bytes as fast as one socket sends; how many."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent, sequence = 0, 0
    deadline = time.monotonic() + seconds
    try:
        while time.monotonic() < deadline:
            for _ in range(100):
                payload = b"\x65" + b"\x00" * (size - 13)
                datagram = build(payload, payload_type=96, sequence=sequence, timestamp=0, ssrc=ssrc, marker=False)
                try:
                    sock.sendto(datagram, target)
                except BlockingIOError:
                    continue
                sequence = (sequence + 1) & 0xFFFF
                sent += 1
    finally:
        sock.close()
    return sent
