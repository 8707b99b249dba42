"""bench/udp.py's report: rounds -> rows (medians), the goal's ratio of the best UDP and TCP paths, where the tail
goes, and the plot."""

from __future__ import annotations

import pytest

from bench.udp_report import Round, Transport, best_ratios, counters_table, plot, row, table, tail_table

TCP = Transport("frames (TCP)", "TCP", ())
RTP = Transport("RTP (UDP)", "UDP", ())
OTHER = Transport("WebRTC (UDP)", "UDP", ())


def rounds(*worst: float, parts: tuple[float, float, float, float] = (10, 1, 20, 10)) -> list[Round]:
    """Rounds of 100 frames at 50 ms but the worst two, a breakdown each."""
    out = []
    for w in worst:
        latencies = [50.0] * 98 + [w, w]
        breakdowns = [
            dict(zip(("uplink_ms", "queue_ms", "inference_ms", "downlink_ms"), parts, strict=True), total_ms=v)
            for v in latencies
        ]
        out.append(Round(100, 98, 9.8, latencies, breakdowns, counters={"nacked": 5.0}))
    return out


def test_a_row_takes_the_median_of_its_rounds_and_shows_their_range():
    got = row(3.0, RTP, rounds(100, 400, 200))
    assert (got.p50, got.p99, got.p99_low, got.p99_high) == (50, 200, 100, 400)
    assert got.unanswered == 6 and got.answered == pytest.approx(0.98) and got.counters == {"nacked": 15.0}
    assert got.tail == {"uplink_ms": 10, "queue_ms": 1, "inference_ms": 20, "downlink_ms": 10}


def test_the_goal_compares_the_best_path_of_each_kind_whatever_the_number_of_paths():
    rows = [
        row(3.0, TCP, rounds(400)),
        row(3.0, RTP, rounds(300)),
        row(3.0, OTHER, rounds(150)),
        row(0.0, RTP, rounds(90)),
    ]
    assert {loss: (u.path, t.path) for loss, (u, t) in best_ratios(rows).items()} == {
        3.0: ("WebRTC (UDP)", "frames (TCP)")
    }
    text = table(rows)
    assert "| 3 % | WebRTC (UDP) | 9.8 | 50 | 150 | 150..150 | 2 | 98% | 0 |" in text
    assert "3 %: best UDP p99 / best TCP p99 = 0.38" in text
    assert "| 3 % | frames (TCP) | 41 | 10 | 1 | 20 | 10 |" in tail_table(rows)
    assert counters_table(rows).count("| 5 |") == 4


def test_the_plot_is_a_png(tmp_path):
    pytest.importorskip("matplotlib", reason="matplotlib is not installed: pip install 'netapp-toolkit[bench]'")
    rows = [row(loss, t, rounds(100 + 50 * loss)) for loss in (0.0, 1.0, 3.0) for t in (TCP, RTP)]
    out = tmp_path / "udp.png"
    plot(rows, str(out), "test")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000
