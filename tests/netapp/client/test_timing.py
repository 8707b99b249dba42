"""The latency breakdown: NTP's offset and delay from the four timestamps, the minimum-delay filter, the split."""

from __future__ import annotations

from netapp.client.timing import ClockOffsetEstimator, breakdown, ntp_sample, server_stamps

MS = 1_000_000


def exchange(t1: int, uplink: int, queue: int, inference: int, reply: int, downlink: int, offset: int):
    """Stamps of one frame: the robot sends at t1 (its clock); the netapp's clock reads robot time + offset."""
    t2 = t1 + uplink + offset
    before = t2 + queue
    after = before + inference
    t3 = after + reply
    t4 = t3 - offset + downlink
    message = {
        "recv_timestamp": t2,
        "timestamp_before_process": before,
        "timestamp_after_process": after,
        "send_timestamp": t3,
    }
    return t1, t4, message


def test_ntp_sample_is_exact_for_a_symmetric_path():
    t1, t4, m = exchange(1_000 * MS, 5 * MS, 2 * MS, 20 * MS, 1 * MS, 5 * MS, offset=-123_456 * MS)
    offset, delay = ntp_sample(t1, m["recv_timestamp"], m["send_timestamp"], t4)
    assert offset == -123_456 * MS and delay == 10 * MS


def test_breakdown_parts_add_up_and_match_the_truth():
    t1, t4, m = exchange(50 * MS, 4 * MS, 3 * MS, 30 * MS, 1 * MS, 4 * MS, offset=7 * 10**12)
    parts = breakdown(t1, t4, server_stamps(m), 7 * 10**12)
    assert (parts.uplink_ms, parts.queue_ms, parts.inference_ms) == (4, 3, 30)
    assert parts.downlink_ms == 5  # the result's serialisation (1 ms) + the network (4 ms)
    assert parts.total_ms == 42 == parts.uplink_ms + parts.queue_ms + parts.inference_ms + parts.downlink_ms


def test_the_minimum_delay_sample_recovers_an_asymmetric_path():
    """A fast, symmetric exchange sets the offset; a later slow uplink is then seen as uplink, not split in half."""
    clock = ClockOffsetEstimator()
    offset = 987_654_321 * MS
    t1, t4, m = exchange(0, 2 * MS, 0, 10 * MS, 0, 2 * MS, offset)
    clock.breakdown(t1, t4, m)
    t1, t4, m = exchange(100 * MS, 80 * MS, 1 * MS, 10 * MS, 0, 2 * MS, offset)  # a congested uplink
    parts = clock.breakdown(t1, t4, m)
    assert clock.offset_ns == offset
    assert (parts.uplink_ms, parts.downlink_ms) == (80, 2)
    single = breakdown(t1, t4, server_stamps(m), ntp_sample(t1, m["recv_timestamp"], m["send_timestamp"], t4)[0])
    assert single.uplink_ms == single.downlink_ms == 41  # what one sample alone would have said


def test_the_filter_forgets_old_samples():
    clock = ClockOffsetEstimator(window=2)
    for i, (off, way) in enumerate(((1 * MS, 1 * MS), (5 * MS, 3 * MS), (5 * MS, 3 * MS))):
        t1, t4, m = exchange(i * 100 * MS, way, 0, 5 * MS, 0, way, off)
        clock.breakdown(t1, t4, m)
    assert clock.offset_ns == 5 * MS  # the best sample (delay 2 ms, offset 1 ms) fell out of the window


def test_a_wrong_offset_never_shows_negative_time_and_parts_still_add_up():
    t1, t4, m = exchange(0, 1 * MS, 2 * MS, 10 * MS, 0, 1 * MS, offset=0)
    for wrong in (-50 * MS, 50 * MS):
        parts = breakdown(t1, t4, server_stamps(m), wrong)
        assert min(parts.uplink_ms, parts.queue_ms, parts.inference_ms, parts.downlink_ms) >= 0
        assert abs(parts.uplink_ms + parts.queue_ms + parts.inference_ms + parts.downlink_ms - parts.total_ms) < 1e-9


def test_messages_without_usable_stamps_give_no_breakdown():
    clock = ClockOffsetEstimator()
    assert clock.breakdown(0, 10, {"detections": []}) is None
    assert clock.breakdown(0, 10, {"recv_timestamp": "1", "timestamp_before_process": 2}) is None
    bad_order = {"recv_timestamp": 9, "timestamp_before_process": 1, "timestamp_after_process": 2, "send_timestamp": 3}
    assert clock.breakdown(0, 10, bad_order) is None
    assert clock.offset_ns is None
