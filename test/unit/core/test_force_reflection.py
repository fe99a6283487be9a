# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Tests of the force reflection logic (core.force_reflection)."""
import math
import threading

from harness.force_reflection import (
    assert_bad_setting_changes_nothing, assert_zero, NO_LIMIT, pose_and_jacobian, reflection, T0,
    WRENCH, ZERO5, ZERO6)
from harness.joints import random_theta
from hypothesis import given, settings, strategies as st
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.force_ramp import DEVICE_WATCHDOG_NS
from kraft_master_driver.core.force_reflection import ForceReflection
from kraft_master_driver.core.wrench_admission import (
    BASE_FRAME, REJECTION_REASONS, WrenchAdmission, WrenchInput, WRIST_FRAME)
import numpy as np
import pytest

TIMEOUT_NS = 50_000_000  # the default wrench_timeout, 0.05 s


def random_wrench(rng):
    """Return a wrench well inside the default max_force and max_moment."""
    return tuple(np.concatenate((rng.uniform(-40, 40, 3), rng.uniform(-4, 4, 3))).tolist())


def compute_once(fr, wrench, frame, theta, **kwargs):
    """Hold wrench, admitted at T0 (tag 42), and compute at T0."""
    admitted = WrenchAdmission().admit(wrench, frame, 0, T0, 0)
    assert type(admitted) is WrenchInput
    fr.hold(admitted._replace(tag=42))
    _, rotation, jac = pose_and_jacobian(theta)
    return fr.compute(rotation, jac, T0, **kwargs)


@pytest.mark.parametrize('seed', range(20))
def test_base_and_wrist_torques_equal_jacobian_transpose_times_wrench(seed):
    rng = np.random.default_rng(seed)
    theta, wrench = random_theta(rng), random_wrench(rng)
    _, rotation, jac = pose_and_jacobian(theta)
    fr = reflection(coupling='joint')

    out = compute_once(fr, wrench, BASE_FRAME, theta)
    expected = jac.T @ np.array(wrench)
    np.testing.assert_allclose(out.actuator, expected[:5], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(out.joint, tuple(expected[:5]) + (0.0,), rtol=1e-12, atol=1e-12)
    assert out.state == 'active' and out.tag == 42 and not out.saturated

    out = compute_once(fr, wrench, WRIST_FRAME, theta)
    base_wrench = np.concatenate((rotation @ wrench[:3], rotation @ wrench[3:]))
    np.testing.assert_allclose(out.actuator, (jac.T @ base_wrench)[:5], rtol=1e-12, atol=1e-12)


def test_wrist_frame_wrench_equals_the_same_wrench_in_base_axes():
    rng = np.random.default_rng(7)
    theta, wrench = random_theta(rng), np.array(random_wrench(rng))
    rotation = kinematics.forward(theta)[:3, :3]
    in_wrist_axes = tuple(np.concatenate((rotation.T @ wrench[:3], rotation.T @ wrench[3:])))
    fr = reflection()
    np.testing.assert_allclose(
        compute_once(fr, in_wrist_axes, WRIST_FRAME, theta).actuator,
        compute_once(fr, tuple(wrench), BASE_FRAME, theta).actuator, rtol=1e-12, atol=1e-12)


def test_force_scale_scales_torques():
    theta = random_theta(np.random.default_rng(3))
    unit = compute_once(reflection(), WRENCH, BASE_FRAME, theta)
    scaled = compute_once(reflection(force_scale=2.5), WRENCH, BASE_FRAME, theta)
    np.testing.assert_allclose(scaled.actuator, 2.5 * np.array(unit.actuator), rtol=1e-12)
    muted = compute_once(reflection(force_scale=0.0), WRENCH, BASE_FRAME, theta)
    assert muted.actuator == ZERO5 and muted.state == 'active'


@pytest.mark.parametrize('seed', range(10))
def test_actuator_coupling_is_the_virtual_work_dual_of_joint_coupling(seed):
    rng = np.random.default_rng(100 + seed)
    theta, wrench = random_theta(rng), random_wrench(rng)
    joint_form = compute_once(reflection(coupling='joint'), wrench, BASE_FRAME, theta)
    actuator_form = compute_once(reflection(coupling='actuator'), wrench, BASE_FRAME, theta)

    t1, t2, t3, t4, t5 = joint_form.actuator
    np.testing.assert_allclose(actuator_form.actuator, (t1, t2 - t3, t3, t4, t5), atol=1e-12)
    np.testing.assert_allclose(
        actuator_form.actuator, kinematics.actuator_torques(joint_form.actuator), atol=1e-12)
    np.testing.assert_allclose(actuator_form.joint, joint_form.joint, atol=1e-12)

    # Same power for any motion of the driven joints: wrench . twist = tau . theta_dot
    # = tau_q . q_dot, with q = (th1, th2, th2 + th3, th4, th5) the actuator coordinates.
    theta_dot = np.append(rng.normal(size=5), 0.0)
    q_dot = theta_dot[:5].copy()
    q_dot[2] = theta_dot[1] + theta_dot[2]
    twist = kinematics.jacobian(theta) @ theta_dot
    power = float(np.dot(wrench, twist))
    assert math.isclose(np.dot(joint_form.actuator, theta_dot[:5]), power, abs_tol=1e-9)
    assert math.isclose(np.dot(actuator_form.actuator, q_dot), power, abs_tol=1e-9)


fraction = st.floats(0.0, 1.0)


@settings(max_examples=200, deadline=None)
@given(st.tuples(*[fraction] * 6),
       st.tuples(*[st.floats(-60, 60)] * 3, *[st.floats(-6, 6)] * 3),
       st.tuples(*[st.floats(0.01, 5.0)] * 5),
       st.sampled_from(('actuator', 'joint')))
def test_saturation_scales_the_whole_vector_and_respects_every_limit(
        fractions, wrench, limits, coupling):
    lower, upper = kinematics.joint_limits()
    theta = lower + np.array(fractions) * (upper - lower)
    lower, upper = kinematics.joint_limits(theta[1])
    theta[2] = lower[2] + fractions[2] * (upper[2] - lower[2])
    free = compute_once(reflection(coupling=coupling), wrench, BASE_FRAME, theta)
    fr = reflection(coupling=coupling, torque_limits=limits)
    out = compute_once(fr, wrench, BASE_FRAME, theta)

    assert all(abs(tau) <= limit for tau, limit in zip(out.actuator, limits))
    free_torques = np.array(free.actuator)
    over = [abs(tau) / limit for tau, limit in zip(free_torques, limits) if abs(tau) > limit]
    factor = 1.0 / max(over) if over else 1.0
    assert out.saturated == bool(over)
    assert fr.counters['saturation_events'] == int(bool(over))
    np.testing.assert_allclose(out.actuator, factor * free_torques, rtol=1e-12, atol=1e-12)
    if out.saturated:
        assert any(math.isclose(abs(tau), limit, rel_tol=1e-12)
                   for tau, limit in zip(out.actuator, limits))
    expected_joint = kinematics.joint_torques_from_actuator(out.actuator) \
        if coupling == 'actuator' else out.actuator
    np.testing.assert_allclose(out.joint, tuple(expected_joint) + (0.0,), atol=1e-12)


def test_saturation_events_count_entries_into_saturation():
    theta = random_theta(np.random.default_rng(5))
    _, rotation, jac = pose_and_jacobian(theta)
    fr = reflection(torque_limits=(0.5,) * 5, coupling='joint')
    strong, weak = tuple(20.0 * x for x in WRENCH), tuple(1e-3 * x for x in WRENCH)
    seen = []
    for wrench in (strong, strong, weak, strong, strong, strong):
        fr.hold(WrenchInput(wrench, BASE_FRAME, T0))
        seen.append(fr.compute(rotation, jac, T0).saturated)
    assert seen == [True, True, False, True, True, True]
    assert fr.counters['saturation_events'] == 2
    assert fr.counters['saturated_cycles'] == 5


def test_disabled_no_wrench_and_cleared_give_zero_torques():
    theta = random_theta(np.random.default_rng(11))
    _, rotation, jac = pose_and_jacobian(theta)
    fr = ForceReflection(torque_limits=NO_LIMIT)
    assert fr.enabled is False
    fr.hold(WrenchInput(WRENCH, BASE_FRAME, T0))
    assert_zero(fr.compute(rotation, jac, T0), 'disabled')

    fr = reflection()
    assert_zero(fr.compute(rotation, jac, T0), 'no_wrench')
    fr.hold(WrenchInput(WRENCH, BASE_FRAME, T0, tag=9))
    assert fr.compute(rotation, jac, T0).tag == 9
    fr.clear()
    assert_zero(fr.compute(rotation, jac, T0), 'no_wrench')
    fr.hold(WrenchInput(WRENCH, BASE_FRAME, T0))
    fr.enabled = False
    assert_zero(fr.compute(rotation, jac, T0), 'disabled')
    fr.enabled = True
    assert fr.compute(rotation, jac, T0).state == 'active'


def test_stale_wrench_gives_zero_torques_and_trips_the_watchdog_once():
    theta = random_theta(np.random.default_rng(12))
    _, rotation, jac = pose_and_jacobian(theta)
    fr = reflection()
    fr.hold(WrenchInput(WRENCH, BASE_FRAME, T0))
    assert fr.compute(rotation, jac, T0 + TIMEOUT_NS).state == 'active'
    for step in range(1, 50):
        assert_zero(fr.compute(rotation, jac, T0 + TIMEOUT_NS + step), 'stale')
    assert fr.counters['watchdog_trips'] == 1
    fr.enabled = False
    fr.compute(rotation, jac, T0 + 2 * TIMEOUT_NS)
    fr.enabled = True
    assert_zero(fr.compute(rotation, jac, T0 + 3 * TIMEOUT_NS), 'stale')
    assert fr.counters['watchdog_trips'] == 1

    later = T0 + 10 * TIMEOUT_NS
    fr.hold(WrenchInput(WRENCH, BASE_FRAME, later))
    assert fr.compute(rotation, jac, later + 1).state == 'active'
    assert_zero(fr.compute(rotation, jac, later + 2 * TIMEOUT_NS), 'stale')
    assert_zero(fr.compute(rotation, jac, later + 3 * TIMEOUT_NS), 'stale')
    assert fr.counters['watchdog_trips'] == 2


def test_receipt_stamped_far_in_the_future_is_stale():
    theta = random_theta(np.random.default_rng(13))
    _, rotation, jac = pose_and_jacobian(theta)
    fr = reflection()
    fr.hold(WrenchInput(WRENCH, BASE_FRAME, T0 + 1000))
    assert fr.compute(rotation, jac, T0).state == 'active'
    fr.hold(WrenchInput(WRENCH, BASE_FRAME, T0 + TIMEOUT_NS + 1))
    assert_zero(fr.compute(rotation, jac, T0), 'stale')


def test_wrench_timeout_change_applies_at_once():
    theta = random_theta(np.random.default_rng(14))
    _, rotation, jac = pose_and_jacobian(theta)
    fr = reflection()
    fr.hold(WrenchInput(WRENCH, BASE_FRAME, T0))
    assert fr.compute(rotation, jac, T0 + 80_000_000).state == 'stale'
    fr.configure(wrench_timeout=0.1)
    assert fr.compute(rotation, jac, T0 + 80_000_000).state == 'active'


nan, inf = math.nan, math.inf


@pytest.mark.parametrize('frame, bad', [
    (BASE_FRAME, 'jacobian'), (WRIST_FRAME, 'rotation'), (WRIST_FRAME, 'jacobian')])
@pytest.mark.parametrize('value', [nan, inf])
def test_non_finite_result_gives_zero_torques(frame, bad, value):
    theta = random_theta(np.random.default_rng(16))
    _, rotation, jac = pose_and_jacobian(theta)
    inputs = {'rotation': rotation.copy(), 'jacobian': jac.copy()}
    inputs[bad][2, 1] = value
    fr = reflection()
    fr.hold(WrenchInput(WRENCH, frame, T0))
    assert_zero(fr.compute(inputs['rotation'], inputs['jacobian'], T0), 'rejected')
    assert fr.counters['non_finite_results'] == 1
    assert fr.compute(rotation, jac, T0).state == 'active'


@pytest.mark.parametrize('seed', range(10))
def test_return_to_centre_spring_pushes_back_toward_the_centre(seed):
    rng = np.random.default_rng(200 + seed)
    centre_theta = random_theta(rng)
    step = np.append(rng.normal(size=5), 0.0)
    theta = centre_theta + 0.05 * step / np.linalg.norm(step)
    centre = kinematics.forward(centre_theta)
    pose, rotation, jac = pose_and_jacobian(theta)
    stiffness = (300.0, 2.0)
    fr = reflection(coupling='joint', centre_stiffness=stiffness)
    fr.hold(WrenchInput(ZERO6, BASE_FRAME, T0))
    out = fr.compute(rotation, jac, T0, pose=pose, centre=centre)

    dp, w = kinematics.pose_difference(pose, centre)
    expected = jac.T @ np.concatenate((-stiffness[0] * dp, -stiffness[1] * w))
    np.testing.assert_allclose(out.actuator, expected[:5], rtol=1e-12, atol=1e-12)
    assert np.dot(out.actuator, (theta - centre_theta)[:5]) < 0.0

    for missing in ({'pose': pose}, {'centre': centre}, {}):
        assert fr.compute(rotation, jac, T0, **missing).actuator == ZERO5
    plain = reflection(coupling='joint')
    plain.hold(WrenchInput(ZERO6, BASE_FRAME, T0))
    assert plain.compute(rotation, jac, T0, pose=pose, centre=centre).actuator == ZERO5


def moving(seed):
    """Return (rotation, jacobian, joint rates, wrist twist) of a random pose and motion."""
    rng = np.random.default_rng(seed)
    _, rotation, jac = pose_and_jacobian(random_theta(rng))
    theta_dot = np.append(rng.normal(size=5), 0.0)
    return rotation, jac, theta_dot, jac @ theta_dot


@pytest.mark.parametrize('seed', range(10))
def test_damping_opposes_velocity(seed):
    rotation, jac, theta_dot, twist = moving(300 + seed)
    damping = (8.0, 0.05)
    fr = reflection(coupling='actuator', centre_damping=damping)
    fr.hold(WrenchInput(ZERO6, BASE_FRAME, T0))
    out = fr.compute(rotation, jac, T0, cartesian_velocity=twist)

    dissipated = damping[0] * twist[:3] @ twist[:3] + damping[1] * twist[3:] @ twist[3:]
    assert dissipated > 0.0
    assert math.isclose(np.dot(out.joint, theta_dot), -dissipated, rel_tol=1e-9)
    assert fr.compute(rotation, jac, T0).actuator == ZERO5


def test_spring_and_damper_add_to_the_scaled_task_wrench():
    rng = np.random.default_rng(17)
    centre_theta = random_theta(rng)
    theta = centre_theta + 0.03
    centre = kinematics.forward(centre_theta)
    pose, rotation, jac = pose_and_jacobian(theta)
    twist = jac @ rng.normal(size=6)
    fr = reflection(coupling='joint', force_scale=0.5, centre_stiffness=(100.0, 1.0),
                    centre_damping=(5.0, 0.02))
    fr.hold(WrenchInput(WRENCH, BASE_FRAME, T0))
    out = fr.compute(rotation, jac, T0, pose=pose, centre=centre, cartesian_velocity=twist)
    dp, w = kinematics.pose_difference(pose, centre)
    total = (0.5 * np.array(WRENCH) - np.concatenate((100.0 * dp, 1.0 * w))
             - np.concatenate((5.0 * twist[:3], 0.02 * twist[3:])))
    np.testing.assert_allclose(out.actuator, (jac.T @ total)[:5], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize('seed', range(5))
def test_contact_damping_grows_with_the_force_and_takes_only_energy(seed):
    rotation, jac, theta_dot, twist = moving(320 + seed)
    fr = reflection(coupling='joint', contact_damping=2.0)
    fr.hold(WrenchInput(WRENCH, BASE_FRAME, T0))
    out = fr.compute(rotation, jac, T0, cartesian_velocity=twist)
    gain = 2.0 * np.linalg.norm(WRENCH[:3])  # N*s/m: 2 s/m times the force
    total = np.array(WRENCH) - np.concatenate((gain * twist[:3], np.zeros(3)))
    np.testing.assert_allclose(out.actuator, (jac.T @ total)[:5], rtol=1e-12, atol=1e-12)
    # Its power is -gain |v|^2: it only takes energy; without a force there is none.
    plain = reflection(coupling='joint')
    plain.hold(WrenchInput(WRENCH, BASE_FRAME, T0))
    undamped = plain.compute(rotation, jac, T0, cartesian_velocity=twist)
    extra = np.dot(np.array(out.joint) - np.array(undamped.joint), theta_dot)
    assert math.isclose(extra, -gain * twist[:3] @ twist[:3], rel_tol=1e-9)
    fr.hold(WrenchInput(ZERO6, BASE_FRAME, T0))
    assert fr.compute(rotation, jac, T0, cartesian_velocity=twist).actuator == ZERO5


@pytest.mark.parametrize('name, value', [
    ('force_scale', -1.0), ('force_scale', nan), ('force_scale', inf), ('force_scale', '2'),
    ('force_scale', True),
    ('torque_limits', (1.0,) * 4), ('torque_limits', (0.0, 1.0, 1.0, 1.0, 1.0)),
    ('torque_limits', (1.0, 1.0, nan, 1.0, 1.0)), ('torque_limits', 'abcde'),
    ('torque_limits', 3.0), ('torque_limits', (1.0, 1.0, 1.0, 1.0, -2.0)),
    ('coupling', 'both'), ('coupling', None),
    ('wrench_timeout', 0.0), ('wrench_timeout', -0.01), ('wrench_timeout', 6.0),
    ('wrench_timeout', nan),
    ('centre_stiffness', (1.0,)), ('centre_stiffness', (-1.0, 0.0)),
    ('centre_damping', (nan, 0.0)), ('centre_damping', (0.0, 0.0, 0.0)),
    ('contact_damping', -1.0), ('contact_damping', inf),
    ('force_ramp_time', -0.01), ('force_ramp_time', 1.5), ('force_ramp_time', nan),
    ('enabled', 'yes'), ('enabled', 1),
])
def test_bad_settings_raise_naming_the_setting_and_change_nothing(name, value):
    valid_change = {'coupling': 'joint'} if name != 'coupling' else {'force_scale': 3.0}
    assert_bad_setting_changes_nothing(ForceReflection, name, value, valid_change)


def test_configure_applies_valid_changes_and_rejects_unknown_names():
    theta = random_theta(np.random.default_rng(18))
    fr = reflection(coupling='joint')
    unit = compute_once(fr, WRENCH, BASE_FRAME, theta)
    fr.configure(force_scale=np.float64(3.0), torque_limits=[400.0, 400, 400, 400, 400.0],
                 centre_damping=np.array([1.0, 0.1]))
    assert fr.force_scale == 3.0 and fr.torque_limits == (400.0,) * 5
    assert fr.centre_damping == (1.0, 0.1)
    tripled = compute_once(fr, WRENCH, BASE_FRAME, theta)
    assert not tripled.saturated
    np.testing.assert_allclose(tripled.actuator, 3.0 * np.array(unit.actuator), rtol=1e-12)
    fr.configure(coupling='actuator')
    assert fr.coupling == 'actuator'
    with pytest.raises(ValueError, match='gain'):
        fr.configure(gain=1.0)
    with pytest.raises(AttributeError):
        fr.force_scale = 2.0
    with pytest.raises(ValueError, match='enabled'):
        fr.enabled = 'on'
    assert fr.enabled is True


def test_counters_start_at_zero():
    counters = ForceReflection().counters
    assert counters == {
        'watchdog_trips': 0, 'age_expiries': 0, 'saturation_events': 0, 'saturated_cycles': 0,
        'non_finite_results': 0, **{f'rejected_{key}': 0 for key in REJECTION_REASONS}}


def test_submissions_and_changes_from_another_thread_never_mix_within_a_cycle():
    theta = random_theta(np.random.default_rng(19))
    _, rotation, jac = pose_and_jacobian(theta)
    other = tuple(-2.0 * x for x in WRENCH)
    expected = set()
    for wrench in (WRENCH, other):
        for scale in (1.0, 2.0):
            expected.add(compute_once(reflection(force_scale=scale), wrench, BASE_FRAME,
                                      theta).actuator)
    fr = reflection()
    fr.hold(WrenchInput(WRENCH, BASE_FRAME, T0))
    done = threading.Event()

    def writer():
        for i in range(20000):
            fr.hold(WrenchInput((WRENCH, other)[i % 2], BASE_FRAME, T0))
            fr.configure(force_scale=(1.0, 2.0)[i % 3 == 0])
        done.set()

    thread = threading.Thread(target=writer)
    thread.start()
    seen = set()
    while not done.is_set():
        out = fr.compute(rotation, jac, T0)
        assert out.state == 'active' and out.actuator in expected
        seen.add(out.actuator)
    thread.join()
    assert len(seen) >= 2


HOLDING = (0.01, 0.5, 0.4, -0.02, 0.03)  # N*m, motor axes 1..5


def test_holding_torques_are_added_to_a_live_wrench_and_alone_only_before_any():
    theta = random_theta(np.random.default_rng(21))
    _, rotation, jac = pose_and_jacobian(theta)
    fr = reflection()
    # No wrench yet: the arm's weight alone.
    alone = fr.compute(rotation, jac, T0, holding=HOLDING)
    assert alone.actuator == HOLDING and alone.state == 'no_wrench'
    np.testing.assert_allclose(alone.joint, kinematics.joint_torques_from_actuator(
        (*HOLDING, 0.0)))
    # A live wrench: its torques and the weight.
    fr.hold(WrenchInput(WRENCH, BASE_FRAME, T0))
    with_wrench = fr.compute(rotation, jac, T0, holding=HOLDING)
    without = fr.compute(rotation, jac, T0)
    np.testing.assert_allclose(np.subtract(with_wrench.actuator, without.actuator), HOLDING)
    # Stale, refused, cleared (several sources), disabled: zero, the weight included.
    assert_zero(fr.compute(rotation, jac, T0 + 2 * TIMEOUT_NS, holding=HOLDING), 'stale')
    fr.hold(WrenchAdmission().admit((math.nan,) * 6, BASE_FRAME, 0, T0, 0))
    assert_zero(fr.compute(rotation, jac, T0, holding=HOLDING), 'rejected')
    fr.clear()
    assert_zero(fr.compute(rotation, jac, T0, holding=HOLDING), 'no_wrench')
    fr.hold(WrenchInput(WRENCH, BASE_FRAME, T0))
    assert fr.compute(rotation, jac, T0, holding=HOLDING).state == 'active'
    fr.enabled = False
    assert_zero(fr.compute(rotation, jac, T0, holding=HOLDING), 'disabled')


def test_at_the_torque_limits_the_weight_stays_and_the_reflected_torques_give_way():
    theta = random_theta(np.random.default_rng(22))
    _, rotation, jac = pose_and_jacobian(theta)
    limits = (0.6,) * 5  # above the weight, below the weight and the wrench together
    free = reflection().compute(rotation, jac, T0, holding=HOLDING)  # the weight alone
    plain = reflection()
    plain.hold(WrenchInput(WRENCH, BASE_FRAME, T0))
    reflected = np.array(plain.compute(rotation, jac, T0).actuator)  # no limits, no weight
    fr = reflection(torque_limits=limits)
    fr.hold(WrenchInput(WRENCH, BASE_FRAME, T0))
    limited = fr.compute(rotation, jac, T0, holding=HOLDING)
    assert limited.saturated
    assert all(abs(tau) <= limit + 1e-12 for tau, limit in zip(limited.actuator, limits))
    # What is left beyond the weight is the reflected torques times one factor below 1.
    share = np.subtract(limited.actuator, free.actuator)
    factor = share @ reflected / (reflected @ reflected)
    assert 0.0 < factor < 1.0
    np.testing.assert_allclose(share, factor * reflected, atol=1e-12)
    # A weight beyond a limit is clamped on its axis alone.
    heavy = reflection(torque_limits=(0.2,) * 5).compute(rotation, jac, T0, holding=HOLDING)
    assert heavy.saturated and heavy.actuator == (0.01, 0.2, 0.2, -0.02, 0.03)


def test_holding_torques_take_the_joint_form_and_non_finite_ones_are_refused():
    theta = random_theta(np.random.default_rng(23))
    _, rotation, jac = pose_and_jacobian(theta)
    joint_device = reflection(coupling='joint').compute(rotation, jac, T0, holding=HOLDING)
    h1, h2, h3, h4, h5 = HOLDING
    assert joint_device.actuator == pytest.approx((h1, h2 + h3, h3, h4, h5))
    nan = reflection().compute(rotation, jac, T0, holding=(math.nan, 0, 0, 0, 0))
    assert_zero(nan, 'rejected')


MS = 1_000_000


class ScaledPort:
    """A master port that passes the wrench on and keeps the shares it is told were applied."""

    def __init__(self):
        self.shares = []

    def step(self, force, velocity, now_ns):
        return force

    def damped(self, velocity):
        return [0.0] * 6

    def scaled(self, factor):
        self.shares.append(factor)

    def idle(self, now_ns):
        pass


def ramped_run(fr, rotation, jac, start_ns, cycles, period_ns=MS, **kwargs):
    """Hold a fresh wrench before each of `cycles` computes, period_ns apart; return them."""
    outputs = []
    for cycle in range(cycles):
        now = start_ns + cycle * period_ns
        fr.hold(WrenchInput(WRENCH, BASE_FRAME, now))
        outputs.append(fr.compute(rotation, jac, now, **kwargs))
    return outputs


def shares(outputs, full):
    """Return each output's torques as a share of the full ones (one number per output)."""
    axis = int(np.argmax(np.abs(full)))
    return [out.actuator[axis] / full[axis] for out in outputs]


def test_force_comes_back_from_zero_over_the_ramp_time_after_every_interruption():
    theta = random_theta(np.random.default_rng(23))
    _, rotation, jac = pose_and_jacobian(theta)
    full = compute_once(reflection(), WRENCH, BASE_FRAME, theta).actuator
    fr = reflection(force_ramp_time=0.05)
    # From the first wrench: 1/50 more a cycle, the direction kept, then the whole force.
    outputs = ramped_run(fr, rotation, jac, T0, 60)
    np.testing.assert_allclose(shares(outputs, full), [min(1.0, n / 50) for n in range(60)],
                               atol=1e-12)
    for out in outputs[1:]:
        np.testing.assert_allclose(np.cross(out.actuator[:3], full[:3]), 0.0, atol=1e-12)
    assert outputs[-1].actuator == pytest.approx(full, abs=1e-12)
    # Stale for a cycle, refused, disabled, no reply from the device: each starts it again.
    now = T0 + 59 * MS
    assert_zero(fr.compute(rotation, jac, now + TIMEOUT_NS + MS), 'stale')
    again = ramped_run(fr, rotation, jac, now + TIMEOUT_NS + 2 * MS, 3)
    assert shares(again, full) == pytest.approx([1 / 50, 2 / 50, 3 / 50])
    now += TIMEOUT_NS + 5 * MS
    fr.hold(WrenchAdmission().admit((math.nan,) * 6, BASE_FRAME, 0, now, 0))
    assert_zero(fr.compute(rotation, jac, now), 'rejected')
    assert shares(ramped_run(fr, rotation, jac, now + MS, 2), full) == pytest.approx(
        [1 / 50, 2 / 50])
    fr.enabled = False
    assert_zero(fr.compute(rotation, jac, now + 3 * MS), 'disabled')
    fr.enabled = True
    assert shares(ramped_run(fr, rotation, jac, now + 4 * MS, 1), full) == pytest.approx(
        [1 / 50])
    fr.interrupt()
    assert shares(ramped_run(fr, rotation, jac, now + 5 * MS, 1), full) == pytest.approx(
        [1 / 50])


def test_a_late_cycle_advances_the_ramp_a_tenth_at_most_and_a_watchdog_gap_starts_it_again():
    theta = random_theta(np.random.default_rng(24))
    _, rotation, jac = pose_and_jacobian(theta)
    full = compute_once(reflection(), WRENCH, BASE_FRAME, theta).actuator
    fr = reflection(force_ramp_time=0.05)
    ramped_run(fr, rotation, jac, T0, 60)  # the whole force
    # 40 ms late (within wrench_timeout): the ramp was not interrupted and the force stays.
    late = ramped_run(fr, rotation, jac, T0 + 99 * MS, 1)
    assert shares(late, full) == pytest.approx([1.0])
    # A gap past wrench_timeout but within the device's watchdog zeroed nothing: the force
    # stays (a restart would drop it, the arm's weight included).
    within = ramped_run(fr, rotation, jac, T0 + 99 * MS + DEVICE_WATCHDOG_NS, 1)
    assert shares(within, full) == pytest.approx([1.0])
    # A gap past the device's watchdog (it may have zeroed its torques): from zero again.
    gap_start = T0 + 99 * MS + 2 * DEVICE_WATCHDOG_NS + MS
    gap = ramped_run(fr, rotation, jac, gap_start, 2)
    assert shares(gap, full) == pytest.approx([0.0, 1 / 50])
    # Cycles 30 ms apart while ramping: a tenth of the ramp each, not 0.6 of it.
    fr.interrupt()
    slow = ramped_run(fr, rotation, jac, gap_start + 31 * MS, 3, period_ns=30 * MS)
    assert shares(slow, full) == pytest.approx([0.1, 0.2, 0.3])


def test_the_weight_ramps_in_too_and_the_port_books_the_share_sent():
    theta = random_theta(np.random.default_rng(25))
    _, rotation, jac = pose_and_jacobian(theta)
    fr = reflection(force_ramp_time=0.01)
    weight = [fr.compute(rotation, jac, T0 + n * MS, holding=HOLDING).actuator
              for n in range(12)]
    np.testing.assert_allclose(weight, [np.multiply(HOLDING, min(1.0, n / 10))
                                        for n in range(12)], atol=1e-12)
    port = ScaledPort()
    fr.interrupt()
    ramped_run(fr, rotation, jac, T0 + 20 * MS, 12, port=port, cartesian_velocity=[0.0] * 6)
    assert port.shares == pytest.approx([n / 10 for n in range(1, 10)])
