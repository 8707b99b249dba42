"""The cameras' watchers, pure: a few per address, and one whose every result is dropped let go after STALL_S."""

from __future__ import annotations

from netapp.server.sources.watchers import MAX_PER_ADDRESS, STALL_S, Watcher, refusal, tell_all


def test_an_address_holds_a_few_watchers_over_every_camera_and_relays_are_not_counted():
    mine = [Watcher("10.0.0.7", False, 0.0) for _ in range(MAX_PER_ADDRESS)]
    assert refusal("yard", {}, mine, "10.0.0.7").reason == "too_many_watchers"
    assert refusal("yard", {}, mine, "10.0.0.8") is None
    relays = [Watcher("10.0.0.9", True, 0.0) for _ in range(MAX_PER_ADDRESS * 3)]  # another replica, one per camera
    assert refusal("yard", {}, relays, "10.0.0.9") is None


def test_a_watcher_whose_results_are_all_dropped_is_let_go_after_stall_s_and_a_reader_never():
    def reader(message: dict) -> bool:
        return True

    def stalled(message: dict) -> bool:
        return False  # its transport dropped it: the robot reads nothing

    watchers = {reader: Watcher("a", False, 0.0), stalled: Watcher("b", False, 0.0)}
    assert tell_all(watchers, {}, STALL_S / 2) == []
    assert watchers[reader].taken_at == STALL_S / 2 and watchers[stalled].taken_at == 0.0
    assert tell_all(watchers, {}, STALL_S) == [stalled]
    assert tell_all({reader: Watcher("a", False, 0.0)}, {}, 100 * STALL_S) == []
