# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The simulated arm's physics and servo, plain Python (the node: test_slave_sim_node.py)."""
import collections
import math

from kraft_master_driver.core.rotations import integrate_quaternion
from kraft_master_driver.simulation.arms.point_mass import (
    ArmServo, MAX_STEP, SlaveArm, SlaveLimits, SoftBox, Wall)
import numpy as np
import pytest

LIMITS = SlaveLimits()
Z = np.array([0.0, 0.0, 1.0])
FLOOR = {'point': (0.0, 0.0, 0.0), 'normal': (0.0, 0.0, 2.0), 'stiffness': 20000.0,
         'damping': 100.0}


def floor_arm(**limits):
    """Return a slave at rest 5 cm above a stiff floor at z = 0."""
    arm = SlaveArm(LIMITS._replace(**limits), wall=Wall(**FLOOR))
    arm.reset((0.0, 0.0, 0.05))
    return arm


def run(arm, seconds, **command):
    """Advance the arm tick by tick (2 ms); return positions, velocities and forces."""
    record = collections.defaultdict(list)
    for _ in range(round(seconds / MAX_STEP)):
        record['force'].append(arm.advance(MAX_STEP, **command))
        record['position'].append(arm.position)
        record['velocity'].append(arm.velocity)
    return {key: np.array(values) for key, values in record.items()}


# -- the wall and the box ----------------------------------------------------------------

def test_wall_pushes_along_its_normal_with_stiffness_and_damping():
    wall = Wall(**FLOOR)
    np.testing.assert_array_equal(wall.normal, Z)
    resting = wall.force(np.array([0.1, -0.2, -0.002]), np.zeros(3))
    np.testing.assert_allclose(resting, [0.0, 0.0, 40.0])
    moving_in = wall.force(np.array([0.0, 0.0, -0.002]), np.array([0.0, 0.0, -0.1]))
    np.testing.assert_allclose(moving_in, [0.0, 0.0, 40.0 + 10.0])
    sliding = wall.force(np.array([0.0, 0.0, -0.002]), np.array([0.3, 0.0, 0.0]))
    np.testing.assert_allclose(sliding, resting)


def test_wall_never_pulls_and_is_silent_in_free_space():
    wall = Wall(**FLOOR)
    leaving_fast = wall.force(np.array([0.0, 0.0, -0.001]), np.array([0.0, 0.0, 1.0]))
    np.testing.assert_array_equal(leaving_fast, np.zeros(3))
    np.testing.assert_array_equal(wall.force(np.array([0.0, 0.0, 1e-9]), -Z), np.zeros(3))
    assert wall.penetration(np.array([5.0, 5.0, -0.003])) == pytest.approx(0.003)


def test_box_pushes_out_through_the_nearest_face():
    box = SoftBox(centre=(1.0, 0.0, 0.0), half_sizes=(0.1, 0.2, 0.3), stiffness=500.0,
                  damping=20.0)
    still = np.zeros(3)
    np.testing.assert_allclose(box.force(np.array([1.09, 0.0, 0.0]), still), [5.0, 0.0, 0.0])
    np.testing.assert_allclose(box.force(np.array([1.0, -0.19, 0.0]), still), [0.0, -5.0, 0.0])
    sinking = np.array([0.0, 0.1, 0.0])
    np.testing.assert_allclose(box.force(np.array([1.0, -0.19, 0.0]), sinking), [0.0, -7.0, 0.0])
    np.testing.assert_array_equal(box.force(np.array([1.0, 0.0, 0.31]), still), still)
    np.testing.assert_array_equal(box.force(np.array([1.0, 0.0, 0.29]), Z), still)


@pytest.mark.parametrize('make, fragment', [
    (lambda: Wall((0, 0, 0), (0, 0, 0), 1.0, 1.0), 'wall.normal'),
    (lambda: Wall((0, 0), (0, 0, 1), 1.0, 1.0), 'wall.point'),
    (lambda: Wall((0, 0, math.nan), (0, 0, 1), 1.0, 1.0), 'wall.point'),
    (lambda: Wall((0, 0, 0), (0, 0, 1), -1.0, 1.0), 'wall.stiffness'),
    (lambda: Wall((0, 0, 0), (0, 0, 1), 1.0, 'soft'), 'wall.damping'),
    (lambda: SoftBox((0, 0, 0), (0.1, 0.0, 0.1), 1.0, 1.0), 'box.half_sizes'),
    (lambda: SlaveArm(LIMITS._replace(mass=0.0)), 'mass'),
    (lambda: SlaveArm(LIMITS._replace(max_velocity=math.inf)), 'max_velocity'),
    (lambda: ArmServo(floor_arm(), 'rate', 0.1), 'mode'),
    (lambda: ArmServo(floor_arm(), 'pose', 0.0), 'command_timeout'),
])
def test_bad_settings_raise_naming_the_setting(make, fragment):
    with pytest.raises(ValueError, match=fragment):
        make()


# -- the slave's servo -------------------------------------------------------------------

def test_free_motion_respects_velocity_and_acceleration_limits_and_arrives():
    arm = SlaveArm(LIMITS)
    arm.reset((0.0, 0.0, 0.0))
    target = np.array([0.3, -0.2, 0.1])
    record = run(arm, 3.0, target=target)
    speeds = np.linalg.norm(record['velocity'], axis=1)
    accelerations = np.linalg.norm(np.diff(record['velocity'], axis=0), axis=1) / MAX_STEP
    assert speeds.max() <= LIMITS.max_velocity * (1 + 1e-9)
    assert speeds.max() > 0.99 * LIMITS.max_velocity
    assert accelerations.max() <= LIMITS.max_acceleration * (1 + 1e-9)
    np.testing.assert_allclose(arm.position, target, atol=1e-5)
    assert not np.any(record['force'])


def test_slave_stops_at_the_wall_and_pushes_with_its_largest_force():
    arm = floor_arm()
    record = run(arm, 2.0, target=np.array([0.0, 0.0, -0.1]))
    depth = -record['position'][:, 2]
    # Hitting the wall at full speed: the energy bound of an undamped wall, plus the push.
    bound = (LIMITS.max_velocity * math.sqrt(LIMITS.mass / FLOOR['stiffness'])
             + LIMITS.mass * LIMITS.max_acceleration / FLOOR['stiffness'])
    assert 0.0 < depth.max() < bound
    steady_push = LIMITS.mass * LIMITS.max_acceleration
    assert depth[-1] == pytest.approx(steady_push / FLOOR['stiffness'], rel=1e-3)
    np.testing.assert_allclose(record['force'][-1], steady_push * Z, rtol=1e-3)
    assert np.all(record['force'][:, 2] >= 0.0)
    np.testing.assert_array_equal(record['force'][:, :2], 0.0)


def test_slave_slides_along_the_wall_to_the_target_projected_onto_it():
    arm = floor_arm()
    run(arm, 3.0, target=np.array([0.2, 0.1, -0.05]))
    np.testing.assert_allclose(arm.position[:2], [0.2, 0.1], atol=1e-5)
    assert -arm.position[2] == pytest.approx(5.0 / FLOOR['stiffness'], rel=1e-3)


def test_slave_sinks_into_the_soft_box_until_its_push_is_balanced():
    arm = SlaveArm(LIMITS, box=SoftBox((0.0, 0.0, -0.5), (0.5, 0.5, 0.5), 200.0, 20.0))
    arm.reset((0.0, 0.0, 0.02))
    record = run(arm, 4.0, target=np.array([0.0, 0.0, -0.3]))
    assert -arm.position[2] == pytest.approx(5.0 / 200.0, rel=1e-3)
    np.testing.assert_allclose(record['force'][-1], [0.0, 0.0, 5.0], rtol=1e-3)


def test_rate_command_moves_at_the_commanded_velocity_clamped_to_the_limit():
    arm = SlaveArm(LIMITS)
    arm.reset((0.0, 0.0, 0.0))
    slow = run(arm, 1.0, velocity=np.array([0.0, 0.1, 0.0]))
    np.testing.assert_allclose(slow['velocity'][-1], [0.0, 0.1, 0.0], atol=1e-9)
    fast = run(arm, 1.0, velocity=np.array([3.0, 0.0, 4.0]))
    np.testing.assert_allclose(fast['velocity'][-1], [0.15, 0.0, 0.2], atol=1e-9)
    run(arm, 1.0, velocity=np.zeros(3))
    np.testing.assert_allclose(arm.velocity, np.zeros(3), atol=1e-12)


def test_a_slave_started_behind_the_wall_starts_on_its_surface():
    arm = floor_arm()
    arm.reset((0.1, 0.2, -0.3))
    np.testing.assert_allclose(arm.position, [0.1, 0.2, 0.0], atol=1e-15)
    record = run(arm, 1.0, target=np.array([0.1, 0.2, -0.3]))
    assert np.abs(record['position'][:, 2]).max() < 0.001


def test_a_long_stall_is_skipped_not_replayed():
    arm = floor_arm()
    arm.advance(10.0, velocity=np.array([0.0, 0.25, 0.0]))
    assert arm.position[1] < 0.25 * 0.1


# -- the servo: commands, timeout, hold ------------------------------------------------

HALF_TURN_ABOUT_Z = (0.0, 0.0, 1.0, 0.0)


def serve(servo, seconds, now, command=None):
    """Advance the servo tick by tick from `now`, sending `command(now)` each tick; return now."""
    for _ in range(round(seconds / MAX_STEP)):
        if command is not None:
            command(now)
        now += MAX_STEP
        servo.advance(MAX_STEP, now)
    return now


def test_the_arm_does_not_move_before_its_first_command():
    arm = SlaveArm(LIMITS)
    arm.reset((0.1, 0.2, 0.3))
    servo = ArmServo(arm, 'pose', timeout=0.1)
    serve(servo, 1.0, 0.0)
    np.testing.assert_array_equal(arm.position, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(arm.velocity, np.zeros(3))
    assert servo.orientation == (0.0, 0.0, 0.0, 1.0)


def test_pose_mode_follows_the_target_and_takes_its_orientation():
    arm = SlaveArm(LIMITS)
    arm.reset((0.0, 0.0, 0.0))
    servo = ArmServo(arm, 'pose', timeout=0.1)
    serve(servo, 2.0, 0.0, lambda t: servo.pose_command((0.05, 0.0, -0.02), HALF_TURN_ABOUT_Z, t))
    np.testing.assert_allclose(arm.position, [0.05, 0.0, -0.02], atol=1e-6)
    assert servo.orientation == HALF_TURN_ABOUT_Z


def test_a_stale_command_holds_the_arm_where_it_was():
    arm = SlaveArm(LIMITS)
    arm.reset((0.0, 0.0, 0.0))
    servo = ArmServo(arm, 'pose', timeout=0.1)
    now = serve(servo, 0.2, 0.0, lambda t: servo.pose_command((1.0, 0.0, 0.0), (0, 0, 0, 1), t))
    assert 0.0 < arm.position[0] < 0.05
    now = serve(servo, 0.1, now)  # the command goes stale within this tenth of a second
    stale_at = servo.hold.copy()
    serve(servo, 2.0, now)
    np.testing.assert_allclose(arm.position, stale_at, atol=1e-6)
    np.testing.assert_allclose(arm.velocity, np.zeros(3), atol=1e-6)


def test_twist_mode_moves_and_turns_at_the_command_then_stops_when_it_is_stale():
    arm = SlaveArm(LIMITS)
    arm.reset((0.0, 0.0, 0.0))
    servo = ArmServo(arm, 'twist', timeout=0.1)
    now = serve(servo, 1.0, 0.0,
                lambda t: servo.twist_command((0.0, 0.1, 0.0), (0.0, 0.0, math.pi / 2), t))
    np.testing.assert_allclose(arm.velocity, [0.0, 0.1, 0.0], atol=1e-9)
    np.testing.assert_allclose(servo.orientation, integrate_quaternion(
        (0, 0, 0, 1), (0.0, 0.0, math.pi / 2), 1.0), atol=1e-9)
    serve(servo, 2.0, now)
    np.testing.assert_allclose(arm.velocity, np.zeros(3), atol=1e-6)
    assert 0.09 < arm.position[1] < 0.1 + LIMITS.max_velocity * 0.1


def test_a_refused_command_holds_the_arm():
    arm = SlaveArm(LIMITS)
    arm.reset((0.0, 0.0, 0.0))
    servo = ArmServo(arm, 'pose', timeout=10.0)
    now = serve(servo, 0.2, 0.0, lambda t: servo.pose_command((1.0, 0.0, 0.0), (0, 0, 0, 1), t))
    with pytest.raises(ValueError, match='unit quaternion'):
        servo.pose_command((1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.5), now)
    servo.refuse()
    position = arm.position.copy()
    serve(servo, 2.0, now)
    assert np.linalg.norm(arm.position - position) < 0.01


@pytest.mark.parametrize('command, fragment', [
    (lambda s: s.pose_command((0.0, math.nan, 0.0), (0, 0, 0, 1), 0.0), 'servo_cp position'),
    (lambda s: s.pose_command((0.0, 0.0), (0, 0, 0, 1), 0.0), 'servo_cp position'),
    (lambda s: s.pose_command((0.0, 0.0, 0.0), (0, 0, math.inf, 1), 0.0), 'unit quaternion'),
    (lambda s: s.twist_command((0.0, 0.0, math.nan), (0, 0, 0), 0.0), 'servo_cv linear'),
    (lambda s: s.twist_command((0.0, 0.0, 0.0), (0, 0), 0.0), 'servo_cv angular'),
])
def test_bad_commands_raise_naming_what_is_wrong(command, fragment):
    with pytest.raises(ValueError, match=fragment):
        command(ArmServo(floor_arm(), 'pose', 0.1))


def test_the_sensor_reading_is_the_contact_force_in_the_tool_frame():
    servo = ArmServo(floor_arm(), 'pose', 0.1)
    np.testing.assert_array_equal(servo.sensor_wrench((1.0, 2.0, 3.0)), [1, 2, 3, 0, 0, 0])
    servo.pose_command((0.0, 0.0, 0.0), HALF_TURN_ABOUT_Z, 0.0)
    np.testing.assert_allclose(servo.sensor_wrench((1.0, 2.0, 3.0)), [-1, -2, 3, 0, 0, 0],
                               atol=1e-12)
