# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Tests of the rules a received wrench must pass (core.wrench_admission), without DDS."""
import math
import threading

from harness.force_reflection import (
    assert_bad_setting_changes_nothing, assert_zero, pose_and_jacobian, reflection, T0, WRENCH)
from harness.joints import random_theta
from kraft_master_driver.core.wrench_admission import (
    BASE_FRAME, Rejection, REJECTION_REASONS, WrenchAdmission, WrenchInput, WRIST_FRAME)
import numpy as np
import pytest

W0 = 1_767_225_600_000_000_000  # an arbitrary time.time_ns() reading
S = 1_000_000_000  # ns
MAX_AGE_NS = 100_000_000  # the default max_wrench_age, 0.1 s
FRAME_IDS = {'kraft_master_base': BASE_FRAME, 'kraft_master_wrist': WRIST_FRAME}
nan, inf = math.nan, math.inf


def admit(wrench=WRENCH, frame_id='kraft_master_base', stamp_ns=W0, empty_is_base=False,
          **settings):
    """Admit a wrench received at T0 (W0 by the system clock) as the driver's admission does."""
    admission = WrenchAdmission(FRAME_IDS, **settings)
    return admission.admit(wrench, frame_id, stamp_ns, T0, W0, empty_is_base)


# -- frame -------------------------------------------------------------------------------------


def test_each_frame_id_of_the_map_gives_its_frame():
    assert admit(frame_id='kraft_master_base') == WrenchInput(WRENCH, BASE_FRAME, T0, W0,
                                                              T0 + MAX_AGE_NS)
    assert admit(frame_id='kraft_master_wrist').frame == WRIST_FRAME
    assert WrenchAdmission().admit(WRENCH, WRIST_FRAME, 0, T0, W0).frame == WRIST_FRAME


@pytest.mark.parametrize('frame_id', ['map', '', 'kraft_master_base ', 'base'])
def test_a_frame_id_not_in_the_map_is_refused_naming_the_frames(frame_id):
    assert admit(frame_id=frame_id) == Rejection(
        'unknown_frame',
        f"frame_id {frame_id!r} is not one of 'kraft_master_base' or 'kraft_master_wrist'")


def test_an_empty_frame_id_is_the_base_frame_where_asked_and_only_there():
    assert admit(frame_id='', empty_is_base=True).frame == BASE_FRAME
    assert admit(frame_id='kraft_master_wrist', empty_is_base=True).frame == WRIST_FRAME
    assert admit(frame_id='', empty_is_base=False).reason == 'unknown_frame'
    assert admit(frame_id='map', empty_is_base=True) == Rejection(
        'unknown_frame',
        "frame_id 'map' is not one of 'kraft_master_base' or 'kraft_master_wrist' or ''")


# -- stamp skew --------------------------------------------------------------------------------


def test_a_stamp_up_to_max_stamp_skew_ahead_of_the_clock_passes():
    assert admit(stamp_ns=W0 + S).expires_ns == T0 + MAX_AGE_NS + S
    assert admit(stamp_ns=W0 + S + 1) == Rejection(
        'bad_timestamp', 'its stamp is -1.000 s off this clock (max_stamp_skew 1 s)')


def test_a_stamp_further_than_max_stamp_skew_behind_the_clock_is_refused_before_its_age():
    assert admit(stamp_ns=W0 - S).reason == 'too_old'
    assert admit(stamp_ns=W0 - S - 1) == Rejection(
        'bad_timestamp', 'its stamp is +1.000 s off this clock (max_stamp_skew 1 s)')
    assert admit(stamp_ns=W0 - 3600 * S).text == (
        'its stamp is +3600.000 s off this clock (max_stamp_skew 1 s)')


def test_an_unset_stamp_passes_the_stamp_rules_and_never_expires():
    assert admit(stamp_ns=0) == WrenchInput(WRENCH, BASE_FRAME, T0, 0, None)


def test_max_stamp_skew_change_applies_to_the_next_wrench():
    admission = WrenchAdmission(FRAME_IDS)
    ahead = W0 + 2 * S
    assert admission.admit(WRENCH, 'kraft_master_base', ahead, T0, W0).reason == 'bad_timestamp'
    admission.configure(max_stamp_skew=2.5)
    assert type(admission.admit(WRENCH, 'kraft_master_base', ahead, T0, W0)) is WrenchInput
    admission.configure(max_stamp_skew=0.001)
    assert admission.admit(WRENCH, 'kraft_master_base', W0 + 1_000_001, T0, W0) == Rejection(
        'bad_timestamp', 'its stamp is -0.001 s off this clock (max_stamp_skew 0.001 s)')


# -- several sources ---------------------------------------------------------------------------


def test_more_than_one_source_is_refused_and_each_change_is_said_once():
    admission = WrenchAdmission(topics=('/right/wrench',))
    several = ('publishers on /right/wrench, only one wrench source is allowed '
               '(allow_multiple_wrench_sources)')
    seen = [admission.count_sources(sources) for sources in (0, 1, 1, 2, 2, 3, 1, 1, 0, 2)]
    assert seen == [
        (False, None), (False, None), (False, None),
        (True, f'2 {several}: torques zeroed'), (True, None),
        (True, f'3 {several}: torques zeroed'),
        (False, '1 publisher(s) on wrench: wrenches accepted'), (False, None), (False, None),
        (True, f'2 {several}: torques zeroed')]
    assert admission.sources == 2 and admission.sources_refusal() == f'2 {several}'
    admission.count_sources(1)
    assert admission.sources == 1 and admission.sources_refusal() is None


def test_the_refusal_of_several_sources_names_every_wrench_topic():
    admission = WrenchAdmission(topics=('/wrench', '/servo_cf'))
    assert admission.count_sources(2)[0]
    assert admission.sources_refusal() == (
        '2 publishers on /wrench and /servo_cf, only one wrench source is allowed '
        '(allow_multiple_wrench_sources)')


def test_several_sources_are_taken_when_allowed():
    admission = WrenchAdmission(allow_multiple_sources=True)
    assert [admission.count_sources(sources) for sources in (1, 2, 5, 1)] == [(False, None)] * 4
    assert admission.sources == 1 and admission.sources_refusal() is None
    with pytest.raises(ValueError, match='allow_multiple_sources'):
        WrenchAdmission(allow_multiple_sources='yes')


# -- finiteness, limits, form ------------------------------------------------------------------


@pytest.mark.parametrize('axis', range(6))
@pytest.mark.parametrize('value', [nan, inf, -inf])
def test_a_non_finite_value_on_any_axis_is_refused(axis, value):
    wrench = [0.0] * 6
    wrench[axis] = value
    assert admit(tuple(wrench)) == Rejection(
        'non_finite', f'non_finite: wrench {tuple(wrench)} is not finite')


def test_a_force_up_to_max_force_passes():
    assert type(admit((120.0, -160.0, 0.0, 0.0, 0.0, 0.0))) is WrenchInput  # |f| = 200 N
    assert admit((120.0, -160.0, 1.0, 0.0, 0.0, 0.0)) == Rejection(
        'force_limit', 'force_limit: |f| = 200.002 N > max_force = 200 N')
    assert admit((0.0, 0.0, 10.5, 0.0, 0.0, 0.0), max_force=10.0).text == (
        'force_limit: |f| = 10.5 N > max_force = 10 N')


def test_a_moment_up_to_max_moment_passes():
    assert type(admit((0.0, 0.0, 0.0, 12.0, 0.0, 16.0))) is WrenchInput  # |m| = 20 N*m
    assert admit((0.0, 0.0, 0.0, 12.0, 0.0, 16.5)) == Rejection(
        'moment_limit', 'moment_limit: |m| = 20.4022 N*m > max_moment = 20 N*m')


@pytest.mark.parametrize('wrench, text', [
    (WRENCH[:5], 'malformed: expected 6 numbers, got 5'),
    ('123456', "malformed: expected 6 numbers, got '123456'"),
    (None, 'malformed: expected 6 numbers, got None'),
])
def test_a_wrench_that_is_not_six_numbers_is_refused(wrench, text):
    assert admit(wrench) == Rejection('malformed', text)


def test_bytes_that_are_not_a_wrench_are_refused_with_the_decoder_s_reason():
    assert WrenchAdmission.malformed('bad frame_id length 0') == Rejection(
        'malformed', 'bad frame_id length 0')


def test_a_receipt_time_that_is_not_integer_ns_is_refused():
    assert WrenchAdmission().admit(WRENCH, BASE_FRAME, 0, 1.5, W0) == Rejection(
        'bad_timestamp', 'bad_timestamp: received_ns must be integer ns, got 1.5')


def test_the_rules_apply_in_order_and_the_first_broken_says_why():
    assert admit((nan,) * 6, 'map', W0 - 5 * S).reason == 'bad_timestamp'
    assert admit((nan,) * 6, 'map', W0 - S // 2).reason == 'non_finite'
    assert admit((1e9,) * 6, 'map', W0 - S // 2).reason == 'unknown_frame'
    assert admit((1e9,) * 6, stamp_ns=W0 - S // 2).reason == 'force_limit'
    assert admit((0.0, 0.0, 0.0, 1e9, 0.0, 0.0), stamp_ns=W0 - S // 2).reason == 'moment_limit'
    assert admit(stamp_ns=W0 - S // 2).reason == 'too_old'


# -- age ---------------------------------------------------------------------------------------


def test_a_wrench_exactly_max_wrench_age_old_passes_and_expires_at_once():
    assert admit(stamp_ns=W0 - MAX_AGE_NS).expires_ns == T0
    assert admit(stamp_ns=W0 - 30_000_000).expires_ns == T0 + 70_000_000


def test_wrench_older_than_max_wrench_age_by_its_stamp_is_refused():
    theta = random_theta(np.random.default_rng(21))
    _, rotation, jac = pose_and_jacobian(theta)
    fr = reflection()
    admission = WrenchAdmission()
    refused = admission.admit(WRENCH, BASE_FRAME, W0 - MAX_AGE_NS - 1, T0, W0)
    fr.hold(refused)
    assert type(refused) is Rejection
    assert refused.text == 'too_old: its stamp is 0.100 s old > max_wrench_age = 0.1 s'
    assert_zero(fr.compute(rotation, jac, T0), 'rejected')
    assert fr.counters['rejected_too_old'] == 1
    admitted = admission.admit(WRENCH, BASE_FRAME, W0 - MAX_AGE_NS, T0, W0)
    assert type(admitted) is WrenchInput
    fr.hold(admitted)
    assert fr.compute(rotation, jac, T0).state == 'active'


def test_wrench_gives_zero_torque_once_its_stamp_is_older_than_max_wrench_age():
    theta = random_theta(np.random.default_rng(22))
    _, rotation, jac = pose_and_jacobian(theta)
    fr = reflection(wrench_timeout=5.0)  # the age by its stamp, not the time since receipt
    age = 70_000_000
    fr.hold(WrenchAdmission().admit(WRENCH, BASE_FRAME, W0 - age, T0, W0))
    assert fr.compute(rotation, jac, T0 + MAX_AGE_NS - age).state == 'active'
    for step in range(1, 50):
        assert_zero(fr.compute(rotation, jac, T0 + MAX_AGE_NS - age + step), 'stale')
    assert fr.counters['age_expiries'] == 1
    assert fr.counters['watchdog_trips'] == 0


def test_unstamped_wrench_is_held_for_wrench_timeout_only():
    theta = random_theta(np.random.default_rng(23))
    _, rotation, jac = pose_and_jacobian(theta)
    fr = reflection(wrench_timeout=0.5)
    fr.hold(WrenchAdmission().admit(WRENCH, BASE_FRAME, 0, T0, W0))
    assert fr.compute(rotation, jac, T0 + 4 * MAX_AGE_NS).state == 'active'
    assert fr.counters['age_expiries'] == 0


def test_max_wrench_age_change_applies_to_the_next_wrench():
    theta = random_theta(np.random.default_rng(24))
    _, rotation, jac = pose_and_jacobian(theta)
    fr = reflection()
    admission = WrenchAdmission()
    admission.configure(max_wrench_age=0.3)
    admitted = admission.admit(WRENCH, BASE_FRAME, W0 - 2 * MAX_AGE_NS, T0, W0)
    assert type(admitted) is WrenchInput
    fr.hold(admitted)
    assert fr.compute(rotation, jac, T0 + 5_000_000).state == 'active'
    assert admission.settings.max_wrench_age == 0.3


# -- a refusal in the force reflection ---------------------------------------------------------


@pytest.mark.parametrize('wrench, frame, received_ns, reason', [
    ((nan, 0, 0, 0, 0, 0), BASE_FRAME, T0, 'non_finite'),
    ((0, 0, 0, 0, 0, inf), WRIST_FRAME, T0, 'non_finite'),
    ((0, -inf, 0, 0, 0, 0), BASE_FRAME, T0, 'non_finite'),
    ((150.0, 150.0, 0, 0, 0, 0), BASE_FRAME, T0, 'force_limit'),
    ((0, 0, -1e30, 0, 0, 0), BASE_FRAME, T0, 'force_limit'),
    ((0, 0, 0, 15.0, 0, -15.0), BASE_FRAME, T0, 'moment_limit'),
    (WRENCH, 'tool', T0, 'unknown_frame'),
    (WRENCH, None, T0, 'unknown_frame'),
    (WRENCH[:5], BASE_FRAME, T0, 'malformed'),
    (WRENCH + (1.0,), BASE_FRAME, T0, 'malformed'),
    ('123456', BASE_FRAME, T0, 'malformed'),
    (None, BASE_FRAME, T0, 'malformed'),
    (('a', 0, 0, 0, 0, 0), BASE_FRAME, T0, 'malformed'),
    (np.zeros((2, 3)), BASE_FRAME, T0, 'malformed'),
    (WRENCH, BASE_FRAME, float(T0), 'bad_timestamp'),
    (WRENCH, BASE_FRAME, None, 'bad_timestamp'),
])
def test_rejected_wrench_zeroes_torques_until_a_valid_one_arrives(
        wrench, frame, received_ns, reason):
    theta = random_theta(np.random.default_rng(15))
    _, rotation, jac = pose_and_jacobian(theta)
    fr = reflection()
    admission = WrenchAdmission()
    fr.hold(admission.admit(WRENCH, BASE_FRAME, W0 - 1, T0, W0))
    before = fr.compute(rotation, jac, T0)
    assert before.state == 'active' and any(before.actuator)

    refused = admission.admit(wrench, frame, W0 - 2, received_ns, W0)
    fr.hold(refused)
    assert type(refused) is Rejection and refused.reason == reason
    for _ in range(3):
        assert_zero(fr.compute(rotation, jac, T0), 'rejected')
    assert fr.rejections == {key: int(key == reason) for key in REJECTION_REASONS}
    assert fr.counters[f'rejected_{reason}'] == 1

    admitted = admission.admit(WRENCH, BASE_FRAME, W0 - 3, T0, W0)
    assert type(admitted) is WrenchInput
    fr.hold(admitted)
    after = fr.compute(rotation, jac, T0)
    assert after.actuator == before.actuator and after.state == 'active' and after.tag == W0 - 3


# -- settings ----------------------------------------------------------------------------------


def test_max_force_and_moment_changes_apply_to_later_wrenches():
    admission = WrenchAdmission()
    assert type(admission.admit(WRENCH, BASE_FRAME, 0, T0, W0)) is WrenchInput
    admission.configure(max_force=1.0)
    assert admission.admit(WRENCH, BASE_FRAME, 0, T0, W0).text.startswith('force_limit')
    admission.configure(max_force=10.0, max_moment=0.1)
    assert admission.admit(WRENCH, BASE_FRAME, 0, T0, W0).text.startswith('moment_limit')


@pytest.mark.parametrize('name, value', [
    ('max_wrench_age', 0.0), ('max_wrench_age', 11.0),
    ('max_force', -1.0), ('max_force', nan), ('max_moment', inf), ('max_moment', None),
    ('max_stamp_skew', 0.0), ('max_stamp_skew', nan), ('max_stamp_skew', '1'),
])
def test_bad_settings_raise_naming_the_setting_and_change_nothing(name, value):
    valid_change = {'max_force': 3.0} if name != 'max_force' else {'max_moment': 3.0}
    assert_bad_setting_changes_nothing(WrenchAdmission, name, value, valid_change)


def test_configure_rejects_unknown_names():
    admission = WrenchAdmission()
    with pytest.raises(ValueError, match='wrench_timeout'):
        admission.configure(wrench_timeout=0.1)
    assert admission.settings == WrenchAdmission().settings


def test_changes_from_another_thread_never_mix_within_one_admission():
    forces_only = {'max_force': 1.0, 'max_moment': 100.0}
    moments_only = {'max_force': 100.0, 'max_moment': 0.01}
    admission = WrenchAdmission(**forces_only)
    done = threading.Event()

    def writer():
        for i in range(20000):
            admission.configure(**(forces_only, moments_only)[i % 2])
        done.set()

    thread = threading.Thread(target=writer)
    thread.start()
    seen = set()
    while not done.is_set():
        refused = admission.admit(WRENCH, BASE_FRAME, 0, T0, W0)
        assert type(refused) is Rejection, 'admitted under a mix of two settings'
        seen.add(refused.reason)
    thread.join()
    assert seen <= {'force_limit', 'moment_limit'}
