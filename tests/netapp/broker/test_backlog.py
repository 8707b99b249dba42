"""The publisher's bounded backlog (netapp/broker/backlog.py): bounds in count and bytes, the oldest gives way and
each loss is counted by why, and an unconfirmed batch goes back to the front in order (at least once)."""

from __future__ import annotations

from netapp.broker.backlog import Backlog, Outgoing


def message(n: int, size: int = 10) -> Outgoing:
    return Outgoing("t", bytes([n % 256]) * size)


def test_count_bound_drops_the_oldest_and_says_why():
    backlog = Backlog(max_count=3, max_bytes=10_000)
    assert [backlog.offer(message(n)) for n in range(3)] == [[], [], []]
    assert backlog.offer(message(3)) == ["count"]
    assert len(backlog) == 3 and backlog.dropped == {"count": 1}
    assert [m.body[0] for m in backlog.take(10, 10_000)] == [1, 2, 3]


def test_byte_bound_and_a_message_larger_than_the_whole_bound():
    backlog = Backlog(max_count=100, max_bytes=25)
    backlog.offer(message(0))
    backlog.offer(message(1))
    assert backlog.offer(message(2)) == ["bytes"] and backlog.bytes == 20
    assert backlog.offer(message(3, size=26)) == ["too_large"] and len(backlog) == 2
    assert backlog.dropped == {"bytes": 1, "too_large": 1}


def test_an_unconfirmed_batch_goes_back_to_the_front_in_order():
    backlog = Backlog(max_count=100, max_bytes=10_000)
    for n in range(5):
        backlog.offer(message(n))
    batch = backlog.take(3, 10_000)
    assert [m.body[0] for m in batch] == [0, 1, 2] and backlog.waiting == 2 and len(backlog) == 5
    backlog.offer(message(5))
    backlog.restore()
    assert [m.body[0] for m in backlog.take(100, 10_000)] == [0, 1, 2, 3, 4, 5]
    backlog.confirm()
    assert len(backlog) == 0 and backlog.bytes == 0


def test_the_batch_in_flight_counts_against_the_bounds_and_is_never_dropped():
    backlog = Backlog(max_count=2, max_bytes=10_000)
    backlog.offer(message(0))
    backlog.offer(message(1))
    backlog.take(2, 10_000)  # both in flight: nothing older waiting to give way
    assert backlog.offer(message(2)) == ["count"] and len(backlog) == 2
    backlog.restore()
    assert [m.body[0] for m in backlog.take(5, 10_000)] == [0, 1]


def test_a_batch_is_bounded_in_bytes_but_never_empty():
    backlog = Backlog(max_count=100, max_bytes=10_000)
    for n in range(4):
        backlog.offer(message(n, size=100))
    assert len(backlog.take(100, 150)) == 2  # the one that crosses the bound still goes
    backlog.confirm()
    assert len(backlog.take(100, 1)) == 1
