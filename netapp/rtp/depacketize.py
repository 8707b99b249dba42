"""H.264 over RTP (RFC 6184) -> access units (Annex B), bounded, never a damaged picture.

Packetisation modes 0 and 1: single NAL unit packets, STAP-A (aggregates) and FU-A (fragments); STAP-B, MTAP and
FU-B (interleaved mode) are refused. Packets are taken in the order given (the netapp puts them in sequence order
first, waiting a little for a lost one asked for again: `netapp.rtp.reorder`); one that comes after a later one
counts as a loss here.

A lost packet (a sequence-number gap) loses the access unit it belonged to, and every later picture references it
until the next keyframe: so from a gap on, every access unit is discarded until one holds an IDR. A damaged picture
therefore never leaves this module, by construction; the caller asks the sender for a keyframe (`need_keyframe`).
The first keyframe handed on must carry its parameter sets (SPS, PPS: a decoder opens with them): the stream's first
packets lost are no gap (nothing was seen before them), so a keyframe without them is one whose first packets never
came (`incomplete`), and the sender is asked for another rather than the pictures waiting for its next keyframe.
Bounds, before a byte is copied: an access unit's bytes and NAL units, a STAP-A's sizes against its packet.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from netapp.rtp.packet import RtpPacket, sequence_after

START_CODE = b"\x00\x00\x00\x01"
NAL_IDR = 5
STAP_A, FU_A = 24, 28
NAL_SLICE, NAL_SEI, NAL_SPS, NAL_PPS, NAL_AUD = 1, 6, 7, 8, 9
MAX_NALS = 256  # per access unit: x264 writes a handful (SPS, PPS, SEI, slices)
DEFAULT_MAX_ACCESS_UNIT_BYTES = 8 * 1024 * 1024  # the netapp passes its --max-payload


@dataclass(frozen=True)
class AccessUnit:
    """One picture's NAL units as an Annex B byte stream, and its RTP timestamp."""

    data: bytes
    rtp_timestamp: int
    keyframe: bool


@dataclass
class Depacketizer:
    """`push` each packet of one stream (payload type and SSRC checked by the caller) in arrival order."""

    max_access_unit_bytes: int = DEFAULT_MAX_ACCESS_UNIT_BYTES
    max_nals: int = MAX_NALS
    need_keyframe: bool = True  # a decoder starts at an IDR; after a loss, again
    _last_sequence: int | None = None
    _timestamp: int | None = None
    _nals: list[bytes] = field(default_factory=list)
    _bytes: int = 0
    _broken: str | None = None  # why the access unit being gathered is lost
    _fragment: bytearray | None = None  # an FU-A NAL unit being reassembled
    _parameter_sets: bool = False  # whether a keyframe with its SPS and PPS was handed on
    # RTP timestamps of the pictures discarded (lost packets, waiting for a keyframe): the caller takes them
    discarded: list[int] = field(default_factory=list)

    def push(self, packet: RtpPacket) -> tuple[list[AccessUnit], list[str]]:
        """(the access units this packet completed, why something was discarded). The reasons: `late` (a duplicate
        or reordered packet, dropped alone), `gap` (a packet lost: its access unit discarded), `malformed`,
        `too_large`, `too_many_nals` (this access unit discarded), `incomplete` (its first packets never came),
        `waiting_keyframe` (a complete access unit discarded because a picture before it was lost)."""
        units: list[AccessUnit] = []
        problems: list[str] = []

        def note(unit: AccessUnit | None, why: str | None) -> None:
            if unit is not None:
                units.append(unit)
            if why:
                problems.append(why)

        gap = False
        if self._last_sequence is not None:
            step = sequence_after(self._last_sequence, packet.sequence)
            if step <= 0:
                return units, ["late"]
            gap = step > 1
        self._last_sequence = packet.sequence
        if self._timestamp is not None and packet.timestamp != self._timestamp:
            if gap and (self._nals or self._fragment is not None):
                self._lose("gap")  # the lost packets may have been its end
            note(*self._finish())  # the previous access unit ended without its marker: as it is (or lost)
        self._timestamp = packet.timestamp
        if gap:  # the lost packets may have been this access unit's beginning
            note(None, self._lose("gap"))
        note(None, self._take(packet))
        if packet.marker:
            note(*self._finish())
        return units, problems

    @property
    def gathering(self) -> bool:
        """Whether an access unit is begun and not finished (its end may have been lost)."""
        return bool(self._nals) or self._broken is not None or self._fragment is not None

    def expire(self) -> str | None:
        """The access unit being gathered will not be finished (no packet came for a while: its last packets, with
        the marker, were lost): it is discarded, and a keyframe needed. Its reason, `timeout`, or None."""
        if not self.gathering:
            return None
        self._lose("timeout")
        self._finish()
        return "timeout"

    def _take(self, packet: RtpPacket) -> str | None:
        """Add the packet's NAL units to the access unit being gathered."""
        if self._broken:
            return None
        payload = packet.payload
        if not payload:
            return self._lose("malformed")
        kind = payload[0] & 0x1F
        if payload[0] & 0x80:  # forbidden_zero_bit
            return self._lose("malformed")
        if 1 <= kind <= 23:
            return self._add(payload)
        if kind == STAP_A:
            at = 1
            while at < len(payload):
                if at + 2 > len(payload):
                    return self._lose("malformed")
                (size,) = struct.unpack_from("!H", payload, at)
                at += 2
                if size == 0 or at + size > len(payload):
                    return self._lose("malformed")
                problem = self._add(payload[at : at + size])
                if problem:
                    return problem
                at += size
            return None
        if kind == FU_A:
            return self._fragment_of(payload)
        return self._lose("malformed")  # STAP-B, MTAP, FU-B, reserved: not in modes 0 and 1

    def _fragment_of(self, payload: bytes) -> str | None:
        if len(payload) < 3:
            return self._lose("malformed")
        indicator, header = payload[0], payload[1]
        start, end = bool(header & 0x80), bool(header & 0x40)
        if start:
            if self._fragment is not None:
                return self._lose("malformed")  # a new NAL unit began before the last one ended
            self._fragment = bytearray([(indicator & 0xE0) | (header & 0x1F)])
        elif self._fragment is None or (self._fragment[0] & 0x1F) != (header & 0x1F):
            return self._lose("malformed")  # a middle or end piece without its start
        if self._bytes + len(self._fragment) + len(payload) > self.max_access_unit_bytes:
            return self._lose("too_large")
        self._fragment += payload[2:]
        if end:
            nal, self._fragment = bytes(self._fragment), None
            return self._add(nal)
        return None

    def _add(self, nal: bytes) -> str | None:
        if len(self._nals) >= self.max_nals:
            return self._lose("too_many_nals")
        if self._bytes + len(START_CODE) + len(nal) > self.max_access_unit_bytes:
            return self._lose("too_large")
        self._nals.append(nal)
        self._bytes += len(START_CODE) + len(nal)
        return None

    def _lose(self, why: str) -> str:
        """The access unit being gathered is lost, and the pictures after it until an IDR."""
        if not self._broken:
            self._broken = why
        self._nals, self._bytes, self._fragment = [], 0, None
        self.need_keyframe = True
        return why

    def _lose_whole(self, why: str) -> str:
        """A gathered access unit that cannot be decoded: discarded, and a keyframe needed."""
        self.need_keyframe = True
        self._discard()
        return why

    def _discard(self) -> None:
        if self._timestamp is not None and len(self.discarded) < MAX_NALS:  # taken after each push: a few at most
            self.discarded.append(self._timestamp)

    def _finish(self) -> tuple[AccessUnit | None, str | None]:
        nals, broken, fragment = self._nals, self._broken, self._fragment
        self._nals, self._bytes, self._broken, self._fragment = [], 0, None, None
        if broken:
            self._discard()
            return None, None  # counted when it broke
        if fragment is not None:  # the marker came inside a fragmented NAL unit: its end is missing
            return None, self._lose_whole("malformed")
        if not nals:
            return None, None
        if not starts_access_unit(nals[0]):  # its first packets never came (before the first one seen, say)
            return None, self._lose_whole("incomplete")
        keyframe = any(nal[0] & 0x1F == NAL_IDR for nal in nals)
        if self.need_keyframe and not keyframe:
            return None, self._lose_whole("waiting_keyframe")
        if keyframe and not self._parameter_sets:
            if not {NAL_SPS, NAL_PPS} <= {nal[0] & 0x1F for nal in nals}:
                return None, self._lose_whole("incomplete")  # its parameter sets were the stream's first packets
            self._parameter_sets = True
        if keyframe:
            self.need_keyframe = False
        assert self._timestamp is not None
        return AccessUnit(b"".join(START_CODE + nal for nal in nals), self._timestamp, keyframe), None


def starts_access_unit(nal: bytes) -> bool:
    """Whether an access unit can begin with this NAL unit (H.264 7.4.1.2.3): SEI, SPS, PPS or an access unit
    delimiter, or a picture's first slice (first_mb_in_slice 0: its exp-Golomb code is the single bit 1)."""
    kind = nal[0] & 0x1F
    if NAL_SEI <= kind <= NAL_AUD:
        return True
    return kind in (NAL_SLICE, NAL_IDR) and len(nal) > 1 and bool(nal[1] & 0x80)
