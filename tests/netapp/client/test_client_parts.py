"""The robot client's parts on their own: the ledger (claim, settle, lose, expire), the wire sequencer (claim
order), the options (transport and codec), and the facade's names (codec, session_state)."""

from __future__ import annotations

import subprocess
import sys
import threading

import numpy as np
import pytest

from netapp.client.ledger import FALLBACK_TARGET, Ledger
from netapp.client.netapp_client import NetAppClient
from netapp.client.options import transport_and_codec
from netapp.client.stats import ClientStats
from netapp.client.wire import WireSequencer
from netapp.protocol import STATE_CHECKPOINT_ARG

FRAME = b"jpeg"


def route_to(*targets: int):
    return lambda now, in_flight_at: list(targets)


def new_ledger() -> tuple[Ledger, ClientStats]:
    stats = ClientStats()
    return Ledger(stats, WireSequencer().ticket, threading.Event()), stats


# -- ledger --------------------------------------------------------------------------------------------------------


def test_a_frame_is_lost_only_when_nobody_answered_and_nobody_holds_it() -> None:
    ledger, stats = new_ledger()
    _, claim = ledger.offer(FRAME, 1, route_to(0, 1))
    assert claim is not None and claim.targets == (0, 1) and ledger.holds(0, 1) and ledger.holds(1, 1)
    sent = ledger.lose(0, 1)  # netapp 0 will not answer; netapp 1 still may
    assert sent is not None and sent.waiting == {1} and stats.lost == 0 and not ledger.holds(0, 1)
    ledger.lose(1, 1)
    assert stats.lost == 1 and ledger.wait_idle(0)
    assert ledger.lose(1, 1) is None and stats.lost == 1  # counted once

    _, claim = ledger.offer(FRAME, 2, route_to(0, 1))
    sent = ledger.settle(0, 2)
    assert sent is not None and ledger.answer(sent) and not ledger.answer(sent)  # the first answer wins
    ledger.lose(1, 2)
    assert stats.lost == 1  # answered: not lost


def test_newest_frame_waits_for_a_slot_and_older_waiting_ones_are_dropped() -> None:
    ledger, stats = new_ledger()
    assert ledger.offer(FRAME, 1, route_to())[1] is None  # no slot: it waits
    assert ledger.offer(b"newer", 2, route_to(0))[1] is None  # one waits already: newest wins, in the same slot
    assert stats.dropped_client == 1
    claim = ledger.claim_waiting(route_to(0), lambda waiting: 0)
    assert claim is not None and (claim.timestamp, claim.frame) == (2, b"newer")
    assert ledger.claim_waiting(route_to(0), lambda waiting: 0) is None  # nothing waits any more


def test_timestamps_never_go_back_and_tickets_follow_claims() -> None:
    ledger, _ = new_ledger()
    t1, c1 = ledger.offer(FRAME, None, route_to(0))
    t2, c2 = ledger.offer(FRAME, t1 - 5, route_to(0))  # a robot's own older timestamp is kept as given...
    t3, c3 = ledger.offer(FRAME, None, route_to(0))  # ...and the next generated one is still after the newest
    assert t2 == t1 - 5 and t3 > t1
    assert [c.ticket for c in (c1, c2, c3)] == [0, 1, 2]  # type: ignore[union-attr]


def test_expiry_counts_a_miss_once_and_loses_a_frame_past_the_timeout() -> None:
    ledger, stats = new_ledger()
    ledger.offer(FRAME, 1, route_to(0, 1, FALLBACK_TARGET))
    assert sorted(ledger.expire(miss_after_ns=-1, timeout_ns=10**12)) == [0, 1]  # the fallback never misses
    assert ledger.expire(miss_after_ns=-1, timeout_ns=10**12) == []  # a miss is counted once per netapp
    assert ledger.expire(miss_after_ns=None, timeout_ns=-1) == [] and stats.lost == 1
    assert not ledger.holds(0, 1) and not ledger.holds(1, 1) and ledger.wait_idle(0)


def test_a_frame_unanswered_for_another_deadline_counts_another_miss() -> None:
    """One frame in flight (the pacer's window) at a link gone silent: the frames held back behind it miss their
    deadlines too, so each further deadline without an answer is one more miss (the policy gives up after two)."""
    ledger, _ = new_ledger()
    ledger.offer(FRAME, 1, route_to(0, FALLBACK_TARGET))
    second = 10**12  # the frame's age is far below this: a `miss_after_ns` this much lower ages it by one period
    assert ledger.expire(miss_after_ns=-1, timeout_ns=10**13, again_ns=second) == [0]
    assert ledger.expire(miss_after_ns=-1, timeout_ns=10**13, again_ns=second) == []  # not within the same period
    assert ledger.expire(miss_after_ns=-second, timeout_ns=10**13, again_ns=second) == [0]  # a deadline later
    assert ledger.expire(miss_after_ns=-3 * second, timeout_ns=10**13, again_ns=second) == [0, 0]  # two more
    assert ledger.holds(0, 1)  # still in flight: its late result may come


def test_a_dropped_link_loses_its_frames_and_frees_its_slots() -> None:
    ledger, stats = new_ledger()
    for timestamp in (1, 2):
        ledger.offer(FRAME, timestamp, route_to(0))
    ledger.lose_all_at(0)
    assert stats.lost == 2 and ledger.wait_idle(0)


def test_the_fallback_takes_over_the_newest_frame_once_and_only_in_time() -> None:
    ledger, _ = new_ledger()
    ledger.offer(FRAME, 1, route_to(0))
    assert ledger.take_over_newest(deadline_ns=-1) is None  # too old already
    assert ledger.take_over_newest(deadline_ns=10**12) == (1, FRAME)
    assert ledger.take_over_newest(deadline_ns=10**12) is None  # it is the fallback's already
    assert ledger.settle(FALLBACK_TARGET, 1) is not None


def test_a_closed_ledger_takes_no_frames() -> None:
    stats, closed = ClientStats(), threading.Event()
    ledger = Ledger(stats, WireSequencer().ticket, closed)
    closed.set()
    with pytest.raises(Exception, match="closed"):
        ledger.offer(FRAME, 1, route_to(0))


# -- wire ----------------------------------------------------------------------------------------------------------


def test_frames_go_on_the_wire_in_ticket_order_whatever_thread_comes_first() -> None:
    wire = WireSequencer()
    tickets = [wire.ticket() for _ in range(4)]
    order: list[int] = []

    def put(ticket: int) -> None:
        with wire.turn(ticket):
            order.append(ticket)

    threads = [threading.Thread(target=put, args=(t,)) for t in reversed(tickets)]  # the last claim starts first
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=10)
    assert order == tickets


def test_a_failed_frame_still_hands_the_wire_on() -> None:
    wire = WireSequencer()
    first, second = wire.ticket(), wire.ticket()
    with pytest.raises(RuntimeError), wire.turn(first):
        raise RuntimeError("the encoder failed")
    done = threading.Event()
    thread = threading.Thread(target=lambda: (wire.turn(second).__enter__(), done.set()))
    thread.start()
    thread.join(timeout=10)
    assert done.is_set()


# -- options and names ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("transport", "codec", "expected"),
    [
        ("http", None, ("http", "jpeg")),
        ("ws", None, ("ws", "jpeg")),
        ("ws", "h264", ("ws", "h264")),
        ("h264", None, ("ws", "h264")),  # the shorthand
        ("h264", "h264", ("ws", "h264")),
        ("frames", None, ("frames", "jpeg")),
        ("frames", "h264", ("frames", "h264")),
    ],
)
def test_transport_and_codec(transport: str, codec: str | None, expected: tuple[str, str]) -> None:
    assert transport_and_codec(transport, codec) == expected


@pytest.mark.parametrize(("transport", "codec"), [("http", "h264"), ("h264", "jpeg"), ("tcp", None), ("ws", "png")])
def test_combinations_that_do_not_exist_are_refused(transport: str, codec: str | None) -> None:
    with pytest.raises(ValueError):
        NetAppClient("http://127.0.0.1:1", transport=transport, codec=codec)


def test_the_facade_names_its_state_and_keeps_the_old_name() -> None:
    client = NetAppClient("http://127.0.0.1:1", transport="http", checkpoint_every=5)
    assert client.session_state is None and client.state is None and client.link_state == "reconnecting"
    assert (client.transport, client.codec, client.args) == ("http", "jpeg", {STATE_CHECKPOINT_ARG: 5})


def test_a_codec_over_socketio_streams_like_the_shorthand(tiny_server) -> None:
    pytest.importorskip("av")
    frame = np.full((96, 128, 3), 90, np.uint8)
    for keywords in ({"transport": "ws", "codec": "h264"}, {"transport": "h264"}):
        with NetAppClient(tiny_server.url, max_in_flight=1, **keywords) as client:
            assert (client.transport, client.codec) == ("ws", "h264")
            for _ in range(5):
                client.send(frame)
                assert client.wait_idle(10)
            assert client.stats.results >= 1 and client.stats.errors == 0, client.stats.summary(1.0)


def test_stream_refuses_a_codec_its_transport_cannot_carry(tiny_server) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "netapp", "stream", tiny_server.url, "--transport", "http", "--codec", "h264"]
        + ["--source", "/no/such.avi"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode != 0 and "needs transport='ws'" in out.stderr


def test_a_new_token_serves_the_next_sessions() -> None:
    """The middleware client gives a switchover's token before `switch_url`: the next session must carry it."""
    client = NetAppClient("http://127.0.0.1:1", transport="http", token="old")
    client.token = "new"
    assert client.token == "new" and client.options.session.token == "new"
    carrier = client._open_session("http://127.0.0.1:1", None)  # type: ignore[arg-type]
    assert carrier.settings.token == "new"


def test_the_adapter_learns_a_result_before_its_slot_frees() -> None:
    # The frame waiting for the slot goes as soon as it frees: with what this result taught the adapter (the first
    # late result of a fall: a smaller frame), not with the settings from before it.
    from types import SimpleNamespace

    from netapp.client.receiver import Receiver

    ledger, stats = new_ledger()
    ledger.offer(FRAME, 1, route_to(0))
    seen: list[bool] = []

    class Adapter:
        def result(self, timestamp: int, latency_ms: float, parts: object) -> dict:
            seen.append(ledger.holds(0, timestamp))
            return {"bytes": 4}

    link = SimpleNamespace(index=0, url="u", measure=lambda *a: None, pace=lambda *a: None)
    delivered: list = []
    switcher = SimpleNamespace(outcome=lambda *a, **k: None)
    delivery = SimpleNamespace(deliver=lambda first, result: delivered.append(result))
    receiver = Receiver([link], ledger, switcher, delivery, None, stats, None, False, threading.Event(), Adapter())  # type: ignore[arg-type]
    receiver.result(link, {"timestamp": 1, "detections": []})  # type: ignore[arg-type]
    assert seen == [True] and delivered[0].sent == {"bytes": 4} and not ledger.holds(0, 1)
