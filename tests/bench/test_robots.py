"""bench/robots.py's own arithmetic: the window every robot streamed in, how robots are spread over processes, and
the model flags the in-process maximum shares with the replicas."""

from __future__ import annotations

from bench.robots import MAX_PROCESSES, robot_processes
from bench.robots_figures import window_rates


def test_rates_are_counted_while_every_robot_gets_results():
    # robot 0 started first and had the netapp to itself (4 results a second); only [1.5, 5.0] is counted
    early = [0.0, 0.25, 0.5, 0.75, 1.0, 2.0, 3.0, 4.0, 5.0]
    late = [1.5, 2.5, 3.5, 4.5, 5.5]
    assert window_rates([early, late]) == [1.0, 1.0]


def test_a_robot_without_results_gets_a_rate_of_zero():
    assert window_rates([[0.0, 1.0, 2.0], []]) == [1.0, 0.0]


def test_robots_are_spread_evenly_where_they_can_be():
    for robots in (6, 8, 16, 12, 9):
        processes = robot_processes(robots)
        assert processes <= MAX_PROCESSES and robots % processes == 0, robots
    assert robot_processes(2) == 2 and robot_processes(7) == MAX_PROCESSES


def test_the_in_process_maximum_reads_the_model_flags_the_replicas_get():
    import argparse

    import pytest

    from bench.robots_worker import model_config

    args = argparse.Namespace(model="seg.onnx", model_args="--conf 0.0001 --max-detections 20 --mask-format rle")
    config = model_config(args)
    assert (config.model_path, config.conf, config.max_detections) == ("seg.onnx", 0.0001, 20)
    assert config.mask_format == "rle"
    assert model_config(argparse.Namespace(model="m.onnx", model_args="")).conf == 0.3  # as before: the defaults
    with pytest.raises(ValueError):
        model_config(argparse.Namespace(model="m.onnx", model_args="--conf 2"))
