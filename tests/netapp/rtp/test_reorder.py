"""Packets back in order, a gap asked for again (RTCP generic NACK) after a timeout that follows the measured round
trip, and given up after its hold; a picture's lost end probed for; NACKs written and read back, bounded."""

from __future__ import annotations

from netapp.rtp.packet import RtpPacket, build, is_rtcp, nack, parse_nack
from netapp.rtp.reorder import INITIAL_RENACK_S, MAX_ASKS, MAX_MISSING, MAX_RTT_S, TAIL_S, Reorder, RttEstimate


def packet(sequence: int, marker: bool = True) -> RtpPacket:
    """A picture's last packet unless `marker` is False (then its picture is open: a tail probe follows)."""
    return RtpPacket(marker, 96, sequence & 0xFFFF, 0, 1, b"\x65")


def sequences(packets) -> list[int]:
    return [p.sequence for p in packets]


def test_a_gap_is_asked_for_and_filled_in_order():
    reorder = Reorder()
    assert sequences(reorder.push(packet(10), 0.0)[0]) == [10]
    ready, asked = reorder.push(packet(13), 0.001)
    assert ready == [] and asked == [11, 12]
    assert reorder.push(packet(12), 0.002) == ([], [])  # held: 11 still missing
    ready, asked = reorder.push(packet(11), 0.04)
    assert sequences(ready) == [11, 12, 13] and reorder.next_deadline() is None
    assert reorder.push(packet(12), 0.05) == (None, [])  # a duplicate (late)


def test_a_gap_is_asked_again_then_given_up_after_its_hold():
    reorder = Reorder()
    reorder.push(packet(65535), 0.0)
    assert reorder.push(packet(1), 0.0) == ([], [0])  # across the wrap
    renack, hold = reorder.rtt.renack_s, reorder.hold_s
    assert reorder.tick(renack - 0.001) == ([], [])
    assert reorder.tick(renack) == ([], [0])
    assert reorder.next_deadline() is not None
    ready, _ = reorder.tick(hold)
    assert sequences(ready) == [1] and reorder.next_deadline() is None and reorder.given_up == 1
    assert reorder.push(packet(0), hold + 0.01) == (None, [])  # too late now: the depacketiser saw the loss


def test_what_is_held_is_bounded():
    reorder = Reorder(max_held=8)
    reorder.push(packet(0), 0.0)
    for s in range(2, 11):
        ready, _ = reorder.push(packet(s), 0.0)
    assert sequences(ready) == list(range(2, 11))  # past 8 held, the gap is given up at once


def test_nack_reads_back_and_a_hostile_one_is_bounded():
    data = nack(1, 2, [5, 6, 9, 21, 22, 40])
    assert is_rtcp(data) and sorted(parse_nack(data)) == [5, 6, 9, 21, 22, 40]
    assert parse_nack(build(b"x", payload_type=96, sequence=1, timestamp=1, ssrc=1, marker=True)) == []
    huge = data[:2] + b"\xff\xff" + data[4:12] + b"\x00\x01\xff\xff" * 10_000
    assert len(parse_nack(huge)) <= 64 * 17
    assert parse_nack(b"\x81\xcd\x00") == []


def test_the_retransmission_timeout_follows_the_measured_round_trip():
    slow, fast = Reorder(), Reorder()
    for reorder, rtt in ((slow, 0.2), (fast, 0.02)):
        at = 0.0
        for base in range(0, 400, 4):  # 100 gaps, each filled one round trip after its NACK
            reorder.push(packet(base), at)
            assert reorder.push(packet(base + 2), at)[1] == [base + 1]
            assert sequences(reorder.push(packet(base + 1), at + rtt)[0]) == [base + 1, base + 2]
            reorder.push(packet(base + 3), at + rtt)
            at += 1.0
        assert abs(reorder.rtt.srtt - rtt) < 0.005 and len(reorder.recovered) == 100
    assert fast.rtt.renack_s < INITIAL_RENACK_S < slow.rtt.renack_s  # never asked again before the answer can come
    assert slow.rtt.renack_s > 0.2 and fast.rtt.renack_s < 0.035
    assert fast.hold_s == MAX_ASKS * fast.rtt.renack_s


def test_a_round_trip_longer_than_the_first_timeout_is_measured_all_the_same():
    """Each gap asked again at 40 ms, before its answer (60 ms) can come: Karn's rule alone would never sample."""
    reorder, rtt, asks = Reorder(), 0.06, []
    at = 0.0
    for base in range(0, 80, 4):
        reorder.push(packet(base), at)
        asked = reorder.push(packet(base + 2), at)[1]
        asked += reorder.tick(at + INITIAL_RENACK_S)[1]  # the timer, 40 ms after the NACK
        asks.append(len(asked))
        reorder.push(packet(base + 1), at + rtt)
        reorder.push(packet(base + 3), at + rtt)
        at += 1.0
    assert asks[0] == 2 and asks[1:] == [1] * 19  # asked again once, before the first answer; then never
    assert abs(reorder.rtt.srtt - rtt) < 0.005 and reorder.rtt.renack_s > rtt


def test_before_any_answer_a_gap_is_held_three_times_40_ms():
    reorder = Reorder()  # a sender that ignores NACKs (udpsink alone) costs this wait on each loss, no more
    assert reorder.rtt.renack_s == INITIAL_RENACK_S and reorder.hold_s == MAX_ASKS * INITIAL_RENACK_S


def test_an_absurd_sample_is_bounded():
    rtt = RttEstimate()
    for _ in range(50):
        rtt.add(1e6)
    assert rtt.srtt == MAX_RTT_S and rtt.hold_s <= MAX_ASKS * MAX_RTT_S
    rtt.add(-5.0)
    assert rtt.srtt > 0


def test_a_missing_packet_is_asked_for_at_most_max_asks_times():
    reorder = Reorder()
    reorder.push(packet(0), 0.0)
    asks = len(reorder.push(packet(2), 0.0)[1])
    now = 0.0
    while (deadline := reorder.next_deadline()) is not None:
        now = deadline
        asks += reorder.tick(now)[1].count(1)
    assert asks == MAX_ASKS and now >= reorder.hold_s and reorder.given_up == 1


def test_a_pictures_lost_last_packet_is_probed_for_without_waiting_for_the_next_picture():
    reorder = Reorder()
    assert sequences(reorder.push(packet(7, marker=False), 0.0)[0]) == [7]
    assert reorder.next_deadline() == TAIL_S
    assert reorder.push(packet(8, marker=False), 0.001)[1] == []  # the burst goes on
    assert reorder.tick(0.001 + TAIL_S - 0.002) == ([], [])
    assert reorder.tick(0.001 + TAIL_S) == ([], [9])  # its marker did not come: asked for
    assert reorder.probes == 1
    ready, asked = reorder.push(packet(9), 0.05)  # the retransmission, with the marker
    assert sequences(ready) == [9] and asked == [] and reorder.next_deadline() is None
    assert reorder.recovered == [0.05 - (0.001 + TAIL_S)]


def test_an_unanswered_probe_is_given_up_and_the_next_picture_is_not_held_for_it():
    reorder = Reorder()
    reorder.push(packet(20, marker=False), 0.0)
    assert reorder.tick(TAIL_S)[1] == [21]
    now = TAIL_S
    while (deadline := reorder.next_deadline()) is not None:
        now = deadline
        reorder.tick(now)
    assert reorder.given_up == 1
    ready, asked = reorder.push(packet(22), now + 0.01)  # the next picture: not a gap to wait for again
    assert sequences(ready) == [22] and asked == []
    assert reorder.push(packet(21), now + 0.02) == (None, [])  # late: the depacketiser saw the loss


def test_a_picture_that_ends_with_its_marker_is_not_probed():
    reorder = Reorder()
    reorder.push(packet(1, marker=False), 0.0)
    reorder.push(packet(2), 0.001)
    assert reorder.next_deadline() is None and reorder.tick(1.0) == ([], []) and reorder.probes == 0


def test_a_jump_past_the_window_starts_again_there_and_walks_no_gap():
    reorder = Reorder()
    reorder.push(packet(0), 0.0)
    assert reorder.push(packet(3), 0.0) == ([], [1, 2])
    ready, asked = reorder.push(packet(32003), 0.001)  # a hostile or broken sender: 32,000 ahead
    assert sequences(ready) == [3, 32003] and asked == []  # what was held goes on, then the stream from the jump
    assert (reorder.restarts, reorder.given_up, reorder.next_deadline()) == (1, 2, None)
    assert sequences(reorder.push(packet(32004), 0.002)[0]) == [32004]
    assert reorder.push(packet(2), 0.003) == (None, [])  # from before the jump: late


def test_a_gap_just_inside_the_window_is_asked_for_whole():
    reorder = Reorder()
    reorder.push(packet(0), 0.0)
    ready, asked = reorder.push(packet(MAX_MISSING + 1), 0.0)
    assert ready == [] and asked == list(range(1, MAX_MISSING + 1)) and reorder.restarts == 0


def test_packets_behind_a_gap_ask_only_for_what_is_new():
    reorder = Reorder()
    reorder.push(packet(0), 0.0)
    assert reorder.push(packet(101), 0.0)[1] == list(range(1, 101))
    for s in range(102, 150):  # each walks nothing of the gap before it
        assert reorder.push(packet(s), 0.0) == ([], [])
    assert reorder.push(packet(152), 0.0) == ([], [150, 151])


def test_jumping_sequence_numbers_never_hold_more_than_the_window():
    reorder = Reorder()
    sequence = 0
    for _ in range(2000):  # each packet 200 ahead of the last: a restart each time, nothing left waiting
        reorder.push(packet(sequence), 0.0)
        assert len(reorder._missing) <= MAX_MISSING
        sequence = (sequence + 200) & 0xFFFF
    assert reorder.restarts == 1999 and reorder.next_deadline() is None
