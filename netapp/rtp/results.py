"""A result carried back to an RTP sender over UDP (`results`): its JSON, compressed with zlib (RFC 1950; a
detector's result repeats its keys, so a crowd's fits one datagram), in an RTCP APP packet named RESULT_APP from the
netapp's SSRC. Both ends use these functions; what comes in is bounded before it is inflated. WebRTC's copy of a
result (its data channel that never resends) is the same compressed JSON: `compressed`, `inflated`."""

from __future__ import annotations

import zlib

from netapp.rtp.packet import RESULT_APP, app, parse_app

MAX_RESULT_BYTES = 256 * 1024  # inflated: a result's JSON larger than this is not one the netapp sends in a datagram
LEVEL = 1  # the fastest: a 2 KB result compresses in microseconds, and only has to fit 1,432 bytes


def result_datagram(sender_ssrc: int, result_json: bytes) -> bytes:
    """The datagram carrying `result_json`; ValueError when it does not fit one (it goes on the transport only)."""
    return app(sender_ssrc, RESULT_APP, compressed(result_json), pad=b"\0")


def compressed(result_json: bytes) -> bytes:
    """`result_json` deflated; ValueError past MAX_RESULT_BYTES (it goes on the session's transport only)."""
    if len(result_json) > MAX_RESULT_BYTES:
        raise ValueError(f"a result over {MAX_RESULT_BYTES} bytes goes on the session's transport only")
    return zlib.compress(result_json, LEVEL)


def result_json(datagram: bytes, sender_ssrc: int) -> bytes | None:
    """The JSON a result datagram from `sender_ssrc` carries; None for anything else: another packet, another SSRC,
    data that is not zlib or inflates past MAX_RESULT_BYTES."""
    parsed = parse_app(datagram, RESULT_APP)
    if parsed is None or parsed[0] != sender_ssrc:
        return None
    return inflated(parsed[1])


def inflated(data: bytes) -> bytes | None:
    """The JSON `compressed` made; None for data that is not zlib or inflates past MAX_RESULT_BYTES."""
    inflater = zlib.decompressobj()
    try:
        data = inflater.decompress(data, MAX_RESULT_BYTES)
    except zlib.error:
        return None
    if inflater.unconsumed_tail or not inflater.eof:  # larger than the bound, or cut short
        return None
    return data
