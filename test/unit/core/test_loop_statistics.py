# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Tests of the loop's bookkeeping: recent samples, cycle statistics."""
from kraft_master_driver.core.loop_statistics import LoopStatistics, RecentSamples
import pytest


# -- RecentSamples -----------------------------------------------------------------------------


def test_no_samples_give_zero_percentiles():
    samples = RecentSamples(8)
    assert samples.recent().size == 0
    assert samples.percentiles_s() == (0.0, 0.0, 0.0)


def test_percentiles_of_the_samples_held_in_seconds():
    samples = RecentSamples(1000)
    for value_ns in range(1, 101):  # 1..100 ms
        samples.add(value_ns * 1_000_000)
    median, p99, peak = samples.percentiles_s()
    assert median == pytest.approx(0.0505)
    assert p99 == pytest.approx(0.09901)
    assert peak == 0.1
    assert all(type(value) is float for value in (median, p99, peak))


def test_only_the_last_size_samples_are_held():
    samples = RecentSamples(4)
    for value in range(1, 11):
        samples.add(value)
    assert samples.count == 10
    assert sorted(samples.recent().tolist()) == [7, 8, 9, 10]
    assert samples.percentiles_s()[2] == 10 / 1e9


# -- LoopStatistics ----------------------------------------------------------------------------


def test_periods_are_the_gaps_between_cycle_starts():
    statistics = LoopStatistics()
    for start_ns in (5_000_000, 6_000_000, 7_500_000, 8_500_000):
        statistics.record_start(start_ns)
    assert statistics.cycles == 3
    assert statistics.periods.recent().tolist() == [1_000_000, 1_500_000, 1_000_000]
    assert statistics.rate_hz() == pytest.approx(3 / 0.0035)


def test_a_loop_that_has_not_cycled_reports_zeros():
    statistics = LoopStatistics()
    statistics.record_start(1_000)  # the first start only sets the clock
    assert statistics.cycles == 0
    assert statistics.rate_hz() == 0.0
    assert statistics.cpu_per_cycle() == {'link': 0.0, 'kinematics': 0.0, 'publish': 0.0}
    assert (statistics.frames, statistics.published, statistics.late, statistics.missed,
            statistics.internal_errors) == (0, 0, 0, 0, 0)


def test_cpu_time_adds_up_per_phase_and_is_shared_out_per_cycle():
    statistics = LoopStatistics()
    for start_ns in range(0, 5_000_000, 1_000_000):  # 4 cycles
        statistics.record_start(start_ns)
    statistics.add_cpu(link=100_000, kinematics=40_000)
    statistics.add_cpu(kinematics=40_000, publish=20_000)
    statistics.add_cpu(link=60_000)
    assert statistics.cpu_ns == {'link': 160_000, 'kinematics': 80_000, 'publish': 20_000}
    assert statistics.cpu_per_cycle() == pytest.approx(
        {'link': 40e-6, 'kinematics': 20e-6, 'publish': 5e-6})


def test_the_window_bounds_the_periods_and_round_trips_held():
    statistics = LoopStatistics(window=3)
    for start_ns in (0, 1_000, 3_000, 6_000, 10_000):
        statistics.record_start(start_ns)
        statistics.round_trips.add(start_ns)
    assert statistics.cycles == 4
    assert sorted(statistics.periods.recent().tolist()) == [2_000, 3_000, 4_000]
    assert statistics.round_trips.recent().size == 3
