# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""A short contact on the MuJoCo Panda in simulated time (harness/teleop_loop.py), no processes."""
from harness.teleop_loop import (
    figures, MAX_FORCE, SENT_BOOKS, Session, tap, Tapping, tapping_figures)
import numpy as np
import pytest

pytestmark = pytest.mark.slow
PUSH = {'past': 0.025, 'hold': 3.0}


@pytest.mark.parametrize('stiffness', [1000.0, 5000.0])
def test_at_0_ms_plain_force_reflection_holds_still_and_is_felt(stiffness):
    result = figures(Session(stiffness=stiffness, **PUSH))
    assert result['master_pp'] <= 0.0005
    assert result['felt_ratio'] >= 0.9
    assert result['felt_stiffness'] >= 0.9 * stiffness * 20000.0 / (stiffness + 20000.0)
    assert result['free_space_drag'] <= 0.5


@pytest.mark.parametrize('stiffness', [1000.0, 5000.0])
def test_at_0_ms_plain_force_reflection_through_whole_pot_counts_holds_still_and_is_felt(
        stiffness):
    # As the driver reads the device: the wrist moves in steps of one count (0.16 mm).
    result = figures(Session(stiffness=stiffness, pot_counts=True, **PUSH))
    assert result['master_pp'] <= 0.0005
    assert result['felt_ratio'] >= 0.85
    assert result['felt_stiffness'] >= 0.85 * stiffness * 20000.0 / (stiffness + 20000.0)
    assert result['free_space_drag'] <= 0.5


@pytest.mark.parametrize('stiffness', [1000.0, 5000.0])
def test_at_0_ms_passivity_booking_the_force_sent_holds_still_and_is_felt(stiffness):
    # doc/design/passivity-experiments.md, Booking the force sent: the slave port books the
    # force sent, the master port a light damper.
    result = figures(Session(stiffness=stiffness, **SENT_BOOKS, **PUSH))
    assert result['master_pp'] <= 0.0005
    assert result['felt_ratio'] >= 0.9
    assert result['felt_stiffness'] >= 0.8 * stiffness * 20000.0 / (stiffness + 20000.0)
    assert result['drift'] <= 0.002
    assert result['free_space_drag'] <= 0.5
    assert result['energy_generated'] <= 0.0


@pytest.mark.parametrize('stiffness', [1000.0, 5000.0])
def test_at_100_ms_booking_the_force_sent_with_more_contact_damping_holds_still_and_is_felt(
        stiffness):
    # The benchmark's 4 s hold: the contact settles over its first second or two.
    result = figures(Session(round_trip_ms=100.0, stiffness=stiffness, contact_damping=50.0,
                             past=0.025, **SENT_BOOKS))
    assert result['master_pp'] <= 0.0005
    assert result['felt_ratio'] >= 0.8
    assert result['energy_generated'] <= 0.0


def test_at_250_ms_passivity_keeps_the_contact_that_plain_force_reflection_shakes():
    plain = figures(Session(round_trip_ms=250.0, **PUSH))
    passive = figures(Session(round_trip_ms=250.0, passivity=True, **PUSH))
    assert plain['master_pp'] > 0.02 and plain['energy_generated'] > 0.5
    assert passive['master_pp'] < 0.005
    assert passive['energy_generated'] <= 0.0


def test_at_250_ms_the_credit_before_the_first_force_cannot_pay_for_following_the_master():
    # doc/design/passivity-experiments.md, What 250 and 500 ms would need: when the contact's
    # first force reaches the master, the master is far
    # past the table; following it would cost the arm more than the master's port has sent.
    result = figures(Session(round_trip_ms=250.0, **SENT_BOOKS, **PUSH))
    series = 1000.0 * 20000.0 / (1000.0 + 20000.0)
    follow = 0.5 * series * result['first_force_past'] ** 2
    assert result['first_force_past'] > 0.015
    assert result['first_force_energy_in'] < 0.2 * follow
    assert result['slave_dissipated'] > 0.4 * (follow - result['first_force_energy_in'])
    assert result['drift'] > 0.01
    assert result['energy_generated'] <= 0.0


def test_at_500_ms_the_contact_model_renders_the_second_touch_still_stiff_and_without_a_step():
    # doc/force-feedback.md: the arm's side estimates the table, the master renders it.
    session = Session(round_trip_ms=500.0, loss=0.01, jitter_ms=5.0, pot_counts=True,
                      force_mode='model', table_stiffness=1000.0)
    touches, run = tapping_figures(session, Tapping(touches=2))
    second = touches[1]
    possible = run['possible_stiffness']
    assert abs(second['master_past'] - second['table_force'] / possible) <= 0.001
    assert second['master_pp'] <= 0.0005
    assert second['felt_stiffness'] >= 0.8 * possible
    assert second['force_step'] <= 1.0
    assert run['max_table_force'] < MAX_FORCE
    assert run['master_first_force'] - run['arm_first_force'] <= 0.5 + 0.05
    assert run['wall_balance'] >= 0.0


def test_auto_switches_to_the_model_and_back_as_the_round_trip_changes_without_a_step():
    # A hold in contact; the round trip steps from 0 to 250 ms at 3 s and back at 6 s.
    session = Session(pot_counts=True, force_mode='auto', table_stiffness=1000.0,
                      round_trip_changes=((3.0, 250.0), (6.0, 0.0)))
    log, _, _ = tap(session, Tapping(touches=1, hold=11.0))
    time, felt, share = log[:, 0], log[:, 5], log[:, 6]
    assert share[(time > 2.0) & (time < 3.0)].max() == 0.0
    assert share[(time > 4.0) & (time < 6.0)].min() == 1.0
    assert share[(time > 11.0) & (time < 11.5)].max() == 0.0
    blending = np.flatnonzero((share > 0.0) & (share < 1.0))
    around = np.unique(np.clip(blending[:, None] + np.arange(-20, 21), 0, len(felt) - 2))
    assert blending.size and np.abs(np.diff(felt))[around].max() <= 0.5
