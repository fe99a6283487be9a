# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Tests of the deadline grid and its rule for late cycles, on a fake clock."""
from kraft_master_driver.core.pacing import Pacer
import pytest

PERIOD_NS = 1_000_000


class FakeClock:
    """Time that moves only when told to or when the pacer sleeps; the sleeps are noted."""

    def __init__(self, now_ns=5_000_300):
        """Start at `now_ns` (off the period, to show the grid's phase is the start's)."""
        self.now_ns = now_ns
        self.sleeps = []

    def monotonic_ns(self):
        return self.now_ns

    def sleep(self, seconds):
        self.sleeps.append(seconds)
        self.now_ns += round(seconds * 1e9)


@pytest.fixture
def clock():
    return FakeClock()


def started(clock):
    pacer = Pacer(PERIOD_NS, clock)
    assert pacer.restart() == clock.now_ns
    return pacer, clock.now_ns


def test_on_time_cycles_sleep_to_each_deadline_of_the_grid(clock):
    pacer, start = started(clock)
    for cycle in range(1, 4):
        clock.now_ns += 300_000  # the cycle's work
        assert pacer.advance() is None
        assert pacer.seconds_left() == pytest.approx(0.0007)
        assert pacer.sleep() == start + cycle * PERIOD_NS
    assert clock.sleeps == pytest.approx([0.0007] * 3)


def test_a_late_wake_up_runs_at_once_and_reports_the_whole_periods_missed(clock):
    pacer, start = started(clock)
    clock.now_ns = start + 4 * PERIOD_NS + 500_000  # the deadline at 1 passed 3.5 periods ago
    assert pacer.advance() == 3
    assert pacer.now_ns == clock.now_ns
    assert pacer.deadline_ns == start + 4 * PERIOD_NS  # on the grid, at or before now
    assert pacer.seconds_left() < 0.0  # due: the late cycle runs at once


def test_a_cycle_late_by_less_than_a_period_misses_none(clock):
    pacer, start = started(clock)
    clock.now_ns = start + PERIOD_NS  # exactly at its deadline counts as late
    assert pacer.advance() == 0
    clock.now_ns = start + 2 * PERIOD_NS + 999_999
    assert pacer.advance() == 0
    assert pacer.deadline_ns == start + 2 * PERIOD_NS


def test_the_grid_keeps_its_phase_after_a_late_cycle_and_never_bursts(clock):
    pacer, start = started(clock)
    clock.now_ns = start + 7 * PERIOD_NS + 250_000
    assert pacer.advance() == 6
    clock.now_ns += 100_000  # the late cycle's work
    assert pacer.advance() is None  # the next deadline is ahead: no cycle to catch up
    assert pacer.sleep() == start + 8 * PERIOD_NS


def test_sleep_does_not_wait_for_a_deadline_that_has_passed(clock):
    pacer, start = started(clock)
    assert pacer.advance() is None
    clock.now_ns = start + PERIOD_NS + 200_000  # the work after advance() overran
    assert pacer.sleep() == clock.now_ns
    assert clock.sleeps == [0.0]


def test_restart_puts_the_grid_at_now(clock):
    pacer, start = started(clock)
    clock.now_ns = start + 2 * PERIOD_NS + 123
    assert pacer.restart() == clock.now_ns
    assert pacer.advance() is None
    assert pacer.deadline_ns == start + 3 * PERIOD_NS + 123


def test_the_period_must_be_positive():
    with pytest.raises(ValueError, match='period'):
        Pacer(0)


def test_the_default_clock_is_the_system_monotonic_one():
    pacer = Pacer(PERIOD_NS)
    start = pacer.restart()
    pacer.advance()  # on time, unless this thread was descheduled for a period
    assert pacer.sleep() >= pacer.deadline_ns >= start + PERIOD_NS
