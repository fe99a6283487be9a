# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Tests of the joint velocity filter (core.velocity_filter)."""
import math

from kraft_master_driver.core.velocity_filter import VelocityFilter
import pytest


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
