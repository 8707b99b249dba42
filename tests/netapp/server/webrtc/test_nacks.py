"""WebRTC's receiver asks for a lost packet again at the measured round trip (aiortc's asks once), and probes for a
picture's lost last packet, with the RTP path's schedule (`netapp.rtp.reorder`)."""

from __future__ import annotations

import asyncio

import pytest

pytest.importorskip("aiortc", reason="aiortc is not installed: pip install 'netapp-toolkit[webrtc]'")

from aiortc.rtcrtpparameters import RTCRtpCodecParameters  # noqa: E402
from aiortc.rtp import RtpPacket  # noqa: E402

from netapp.rtp.reorder import INITIAL_RENACK_S, MAX_ASKS, TAIL_S  # noqa: E402
from netapp.server.webrtc import nacks  # noqa: E402

RTT_S = 0.03


def packet(sequence: int, marker: bool = True) -> RtpPacket:
    return RtpPacket(payload_type=96, sequence_number=sequence, timestamp=3000 * sequence, marker=int(marker), ssrc=7)


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


async def never_sent(ssrc: int, lost: list[int]) -> None:
    raise AssertionError("the timer is not run in these tests: `due` is called instead")


async def test_a_lost_retransmission_is_asked_for_again_at_the_measured_round_trip():
    clock, nacked, recovered = Clock(), [], []
    asker = nacks.TimedNacks(never_sent, clock, nacked.append, recovered.append)
    # round trips measured: a gap a frame, its packet sent again RTT_S later
    for n in range(0, 60, 3):
        asker.add(packet(n))
        assert asker.add(packet(n + 2)) and asker.missing == [n + 1]
        clock.now += RTT_S
        asker.add(packet(n + 1))
        clock.now += 0.07
    renack = asker.reorder.rtt.renack_s
    assert RTT_S < renack < INITIAL_RENACK_S + 0.005  # the measured round trip, its margin
    asker.add(packet(60))
    assert asker.add(packet(62)) and asker.missing == [61]
    asked_at = clock.now
    clock.now = asked_at + RTT_S  # the retransmission is lost: nothing yet, within the round trip
    assert asker.due(clock.now) == []
    clock.now = asked_at + renack
    assert asker.due(clock.now) == [61]  # asked again: aiortc's generator never would without another gap
    clock.now += renack
    assert asker.due(clock.now) == [61]
    assert (sum(nacked), sum(recovered)) == (20 + MAX_ASKS, 20)  # then given up, after MAX_ASKS asks
    clock.now += renack
    assert asker.due(clock.now) == []
    asker.close()


async def test_a_pictures_lost_last_packet_is_probed_for_before_the_next_picture():
    clock = Clock()
    asker = nacks.TimedNacks(never_sent, clock)
    asker.add(packet(10))
    assert not asker.add(packet(11, marker=False))  # its marker (12) is lost
    clock.now += TAIL_S
    assert asker.due(clock.now) == [12]
    asker.close()


async def test_the_receiver_of_a_peer_connection_asks_again_from_a_timer():
    """aiortc's own receiver NACKs the gap once; installed, the same receiver asks again a round trip later."""
    import aiortc.rtcpeerconnection

    nacks.install()
    transport = type("Transport", (), {"state": "new"})()
    receiver = aiortc.rtcpeerconnection.RTCRtpReceiver("video", transport)
    receiver._RTCRtpReceiver__codecs[96] = RTCRtpCodecParameters(mimeType="video/VP8", clockRate=90000, payloadType=96)
    receiver._set_rtcp_ssrc(1)
    nacked: list[list[int]] = []

    async def send(rtcp: object) -> None:
        nacked.append(list(getattr(rtcp, "lost", [])))

    receiver._send_rtcp = send
    for n in (1, 2, 4):
        await receiver._handle_rtp_packet(packet(n), 0)
    assert nacked == [[3]]
    await asyncio.sleep(INITIAL_RENACK_S * 1.5)  # no packet came since: its copy, then the timer asks again
    assert len(nacked) >= 3 and set(map(tuple, nacked)) == {(3,)}, nacked
    await receiver.stop()


async def test_each_nack_is_sent_twice_unless_the_packet_came_between():
    """A NACK lost, or the retransmission it asked for, costs no retransmission timeout: it goes twice, AGAIN_S apart
    (the second only for what is still missing), and the sender answers each."""
    sent: list[list[int]] = []
    copies: asyncio.Queue[list[int]] = asyncio.Queue()

    async def send(ssrc: int, lost: list[int]) -> None:
        sent.append(lost)
        copies.put_nowait(lost)

    asker = nacks.TimedNacks(send)
    asker.add(packet(1))
    assert asker.add(packet(3)) and asker.missing == [2]  # aiortc's receiver sends this one
    assert await asyncio.wait_for(copies.get(), 1) == [2]  # and its copy goes AGAIN_S later
    asker.add(packet(2))  # recovered: never asked again
    assert asker.add(packet(6)) and asker.missing == [4, 5]
    asker.add(packet(4))  # came before the copy: only 5 is asked for again
    assert await asyncio.wait_for(copies.get(), 1) == [5]
    assert sent == [[2], [5]]
    asker.close()
