"""The `rtp` transport's bookkeeping of answers that come twice (a datagram, the WebSocket): the first copy is
delivered with the frame's own timestamp, the second is not, and only the WebSocket's order drops frames."""

from __future__ import annotations

from netapp.client.transports.rtp_answers import Answers


def sent(*pairs: tuple[int, int], remembered: int = 256) -> Answers:
    answers = Answers(remembered)
    for rtp_timestamp, timestamp in pairs:
        answers.sent(rtp_timestamp, timestamp)
    return answers


def test_the_datagram_first_then_its_websocket_copy_is_not_delivered_again():
    answers = sent((900, 1), (1800, 2))
    assert answers.from_datagram(900) == 1
    assert answers.from_datagram(900) is None  # a duplicated datagram
    copy = answers.from_websocket(900)
    assert copy.timestamp == 1 and not copy.deliver and copy.dropped == []


def test_the_websocket_first_then_its_datagram_is_not_delivered():
    answers = sent((900, 1))
    first = answers.from_websocket(900)
    assert first.timestamp == 1 and first.deliver
    assert answers.from_datagram(900) is None


def test_a_later_frames_datagram_drops_nothing_before_it_but_the_websocket_does():
    answers = sent((900, 1), (1800, 2), (2700, 3))
    assert answers.from_datagram(2700) == 3  # frame 1's and 2's answers may still come on the WebSocket
    assert answers.from_websocket(900).deliver  # frame 1's datagram was lost: its WebSocket copy counts
    third = answers.from_websocket(2700)  # the WebSocket is in order: frame 2 was never answered
    assert third.dropped == [2] and not third.deliver


def test_the_rtp_timestamp_is_32_bits_and_what_is_kept_is_bounded():
    answers = sent(*((k, k) for k in range(10)), remembered=4)
    assert answers.from_datagram(3) is None  # forgotten: only the last 4 kept
    assert answers.from_datagram(9 + (1 << 32)) == 9  # the netapp's unwrapped timestamp
    stale = answers.from_websocket(12345)
    assert stale.timestamp is None and stale.deliver  # not ours: as it is
    assert answers.superseded(8) == 8 and answers.superseded(8) is None
