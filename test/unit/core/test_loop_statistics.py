# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Tests of the loop's bookkeeping: recent samples, cycle statistics, the velocity filter."""
import math

from kraft_master_driver.core.loop_statistics import LoopStatistics, RecentSamples, VelocityFilter
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


# -- VelocityFilter ----------------------------------------------------------------------------


def test_the_first_sample_gives_rest():
    velocity = VelocityFilter(50.0, size=2)
    assert velocity.update([1.0, 2.0], 1_000_000) == [0.0, 0.0]


def test_one_step_is_the_finite_difference_through_the_low_pass():
    velocity = VelocityFilter(50.0, size=2)
    velocity.update([0.0, 1.0], 0)
    result = velocity.update([0.001, 0.998], 1_000_000)  # 1 rad/s and -2 rad/s over 1 ms
    alpha = 1.0 - math.exp(-2.0 * math.pi * 50.0 * 0.001)
    assert result == pytest.approx([alpha * 1.0, alpha * -2.0])
    assert all(type(value) is float for value in result)


def test_a_steady_motion_converges_to_its_velocity():
    velocity = VelocityFilter(50.0, size=1)
    for step in range(200):  # 0.2 s at 1 kHz, 10 time constants of the filter
        result = velocity.update([0.5 * step * 0.001], step * 1_000_000)
    assert result == pytest.approx([0.5], rel=1e-3)


def test_a_sample_that_does_not_move_the_clock_on_changes_nothing():
    velocity = VelocityFilter(50.0, size=1)
    velocity.update([0.0], 1_000_000)
    first = velocity.update([0.001], 2_000_000)
    assert velocity.update([5.0], 2_000_000) == first  # same time: no division by zero
    assert velocity.update([5.0], 1_500_000) == first  # earlier: ignored too


def test_a_higher_cutoff_follows_faster():
    slow, fast = VelocityFilter(5.0, size=1), VelocityFilter(500.0, size=1)
    for filter_ in (slow, fast):
        filter_.update([0.0], 0)
        filter_.update([0.001], 1_000_000)
    assert 0.0 < slow.value[0] < fast.value[0] < 1.0


def test_the_cutoff_may_change_between_samples():
    velocity = VelocityFilter(5.0, size=1)
    velocity.update([0.0], 0)
    velocity.cutoff_hz = 1e6  # alpha of about 1: the raw difference
    assert velocity.update([0.002], 1_000_000) == pytest.approx([2.0])


def test_reset_forgets_the_history():
    velocity = VelocityFilter(50.0, size=2)
    velocity.update([0.0, 0.0], 0)
    velocity.update([0.01, 0.01], 1_000_000)
    velocity.reset()
    assert velocity.value == [0.0, 0.0]
    # After a gap (a link fault), the next sample starts from rest, not from a jump.
    assert velocity.update([5.0, -5.0], 500_000_000) == [0.0, 0.0]
