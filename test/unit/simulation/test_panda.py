# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The MuJoCo Panda, its Cartesian impedance controller, its F/T sensor and its table."""
import pathlib

from kraft_master_driver.core.rotations import (
    rotation_from_vector, rotation_to_quaternion, rotation_vector)
from kraft_master_driver.simulation.arms.panda import (
    franka_assets, Gains, HOME, PandaArm, SensorModel, Table, TORQUE_LIMITS,
    TORQUE_RATE_LIMIT)
import numpy as np
import pytest

GRAVITY = np.array([0.0, 0.0, -9.81])


@pytest.fixture(scope='module')
def arm():
    """Build one arm for the module (that compiles the meshes); each test resets it."""
    return PandaArm()


@pytest.fixture
def fresh(arm):
    """Return the arm at rest at HOME, with no command."""
    arm.reset(HOME)
    return arm


def run(arm, seconds, target=None, quaternion=None, twist=None):
    """Step `seconds`, commanding a pose or a twist every step; return torques, their task part."""
    torques, task = [], []
    for _ in range(round(seconds / arm.model.opt.timestep)):
        if target is not None:
            assert arm.command_pose(target, quaternion, arm.time) is None
        if twist is not None:
            assert arm.command_twist(twist[:3], twist[3:], arm.time) is None
        arm.step()
        torques.append(arm.torque.copy())
        task.append(arm.task_torque.copy())
    return np.array(torques), np.array(task)


def contact_reading(arm):
    """Return the sensor's force less the tool's weight, in the arm's base frame (N)."""
    mass, _ = arm.tool_mass_properties()
    return arm.sensor_rotation() @ arm.wrench()[:3] - mass * GRAVITY


def test_the_model_is_the_installed_packages_panda(fresh):
    assets = franka_assets()
    assert 'gymnasium_robotics' in assets.parts
    assert pathlib.Path(assets, 'chain.xml').read_text().count('panda0_joint') >= 7
    # Franka's joint ranges, as the package's chain gives them (rad).
    np.testing.assert_allclose(fresh.joint_range[[0, 1, 3]],
                               [[-2.8973, 2.8973], [-1.7628, 1.7628], [-3.0718, -0.4]])
    mass, com = fresh.tool_mass_properties()
    assert mass == pytest.approx(1.0045, abs=1e-3)  # hand and fingers
    assert 0.0 < com[2] < 0.1
    # At HOME the hand points down, the tool frame x forward.
    np.testing.assert_allclose(fresh.tool_rotation(), np.diag([1.0, -1.0, -1.0]), atol=0.01)
    assert fresh.model.opt.timestep == 0.001


def test_with_no_command_the_arm_holds_still_and_the_sensor_reads_the_tools_weight(fresh):
    start = fresh.tool_position()
    run(fresh, 1.0)
    assert np.linalg.norm(fresh.tool_position() - start) < 1e-4
    assert np.abs(fresh.joint_velocities()).max() < 1e-3
    mass, com = fresh.tool_mass_properties()
    # The wrench the tool applies to the sensor: its weight, and the moment of it.
    reading = fresh.wrench()
    weight = fresh.sensor_rotation().T @ (mass * GRAVITY)
    np.testing.assert_allclose(reading[:3], weight, atol=1e-3)
    np.testing.assert_allclose(reading[3:], np.cross(com, weight), atol=1e-3)


def test_tracking_a_pose_converges(fresh):
    target = fresh.tool_position() + (0.1, -0.08, 0.1)
    turned = rotation_from_vector((0.0, 0.0, 0.3)) @ fresh.tool_rotation()
    run(fresh, 3.0, target, rotation_to_quaternion(turned))
    assert np.linalg.norm(fresh.tool_position() - target) < 0.002
    assert np.linalg.norm(rotation_vector(fresh.tool_rotation() @ turned.T)) < 0.01
    assert np.abs(fresh.joint_velocities()).max() < 0.01


def test_a_twist_moves_the_target_and_a_stale_twist_stops_the_arm(fresh):
    start = fresh.tool_position()
    run(fresh, 1.0, twist=(0.05, 0.0, 0.0, 0.0, 0.0, 0.0))
    run(fresh, 0.5)  # the last twist goes stale: hold where measured
    moved = fresh.tool_position() - start
    assert moved[0] == pytest.approx(0.05, abs=0.01)
    assert abs(moved[1]) < 0.005 and abs(moved[2]) < 0.005
    held = fresh.tool_position()
    run(fresh, 1.0)
    assert np.linalg.norm(fresh.tool_position() - held) < 0.005
    assert np.abs(fresh.joint_velocities()).max() < 0.01


def test_a_stale_command_holds_the_arm_still_where_it_is(fresh):
    quaternion = fresh.tool_quaternion()
    far = fresh.tool_position() + (0.3, 0.0, 0.0)
    run(fresh, 0.1, far, quaternion)  # moving toward it, then no more commands
    run(fresh, fresh.command_timeout)
    assert fresh.holding
    stopped = fresh.tool_position()
    run(fresh, 2.0)
    assert np.linalg.norm(fresh.tool_position() - stopped) < 0.01
    assert np.linalg.norm(fresh.tool_position() - far) > 0.1  # short of the stale target
    assert np.abs(fresh.joint_velocities()).max() < 0.01


def test_joint_and_torque_limits_hold_for_a_target_out_of_reach(fresh):
    quaternion = fresh.tool_quaternion()
    torques, task = run(fresh, 3.0, (1.5, 1.0, 1.2), quaternion)
    assert np.all(np.abs(torques) <= TORQUE_LIMITS + 1e-9)
    assert np.abs(torques).max(axis=0)[3] > 20.0  # it does pull
    # Beyond gravity and Coriolis, the torque changes by at most 1 N*m a step.
    steps = np.abs(np.diff(task, axis=0))
    assert steps.max() <= TORQUE_RATE_LIMIT * fresh.model.opt.timestep + 1e-9
    assert np.abs(fresh.joint_velocities()).max() < 2.175  # Franka's slowest joint's limit
    low, high = fresh.joint_range.T
    joints = fresh.joint_positions()
    assert np.all(joints >= low - 0.01) and np.all(joints <= high + 0.01)


def test_pressing_on_the_table_the_sensor_reads_the_contact_force(fresh):
    quaternion = fresh.tool_quaternion()
    start = fresh.tool_position()
    table_top = 0.4
    assert start[2] > table_top
    run(fresh, 0.2)
    assert np.all(fresh.table_contact_force() == 0.0)
    np.testing.assert_allclose(contact_reading(fresh), 0.0, atol=1e-3)

    target = start - (0.0, 0.0, start[2] - table_top + 0.03)  # 3 cm into the table
    run(fresh, 3.0, target, quaternion)
    contact = fresh.table_contact_force()
    assert fresh.tool_position()[2] == pytest.approx(table_top, abs=0.002)
    # The table pushes up with about the impedance's spring force, and the sensor reads it.
    assert contact[2] == pytest.approx(
        fresh.gains.translational_stiffness * 0.03, rel=0.1)
    np.testing.assert_allclose(contact_reading(fresh), contact, atol=0.05)
    # The table top's spring carries it: the table's stiffness times how far the top sank.
    assert contact[2] == pytest.approx(Table().stiffness * fresh.table_deflection(), rel=0.02)


def test_a_softer_table_gives_way_more_under_the_same_push():
    soft = PandaArm(table=Table(stiffness=2000.0, damping=30.0))
    quaternion = soft.tool_quaternion()
    target = soft.tool_position() - (0.0, 0.0, soft.tool_position()[2] - 0.4 + 0.03)
    run(soft, 3.0, target, quaternion)
    contact = soft.table_contact_force()
    assert contact[2] > 5.0
    assert soft.table_deflection() == pytest.approx(contact[2] / 2000.0, rel=0.02)
    np.testing.assert_allclose(contact_reading(soft), contact, atol=0.05)


def test_bias_and_noise_are_added_to_the_reading():
    sensor = SensorModel(force_bias=(1.0, -2.0, 3.0), torque_bias=(0.1, 0.2, -0.3),
                         force_noise=0.5, torque_noise=0.02)
    noisy = PandaArm(sensor=sensor, seed=1)
    clean = noisy.wrench() - np.concatenate((sensor.force_bias, sensor.torque_bias))
    noisy.sensor = SensorModel()
    exact = noisy.wrench()
    noisy.sensor = sensor
    readings = np.array([noisy.wrench() for _ in range(4000)])
    bias = np.concatenate((sensor.force_bias, sensor.torque_bias))
    np.testing.assert_allclose(readings.mean(axis=0) - bias, exact, atol=0.05)
    np.testing.assert_allclose(readings[:, :3].std(axis=0), 0.5, rtol=0.1)
    np.testing.assert_allclose(readings[:, 3:].std(axis=0), 0.02, rtol=0.1)
    assert not np.allclose(clean, exact)  # one reading is noisy


@pytest.mark.parametrize('command, reason', [
    (((float('nan'), 0.0, 0.5), (0.0, 0.0, 0.0, 1.0)), 'servo_cp position must be 3 finite'),
    (((0.3, 0.0, 0.5), (0.0, 0.0, 0.0, 2.0)), 'is not a unit quaternion'),
    (((0.3, 0.0), (0.0, 0.0, 0.0, 1.0)), 'servo_cp position must be 3 finite'),
])
def test_a_bad_command_is_refused_in_one_line_and_the_arm_holds(fresh, command, reason):
    start = fresh.tool_position()
    refusal = fresh.command_pose(*command, fresh.time)
    assert reason in refusal and '\n' not in refusal
    assert 'servo_cv angular' in fresh.command_twist((0, 0, 0), (0, float('inf'), 0), 0.0)
    run(fresh, 0.5)
    assert np.linalg.norm(fresh.tool_position() - start) < 1e-4


@pytest.mark.parametrize('make, name', [
    (lambda: Table(height=-0.1), 'table.height'),
    (lambda: Table(stiffness=0.0), 'table.stiffness'),
    (lambda: Table(half_sizes=(0.2, -0.1)), 'table.half_sizes'),
    (lambda: Gains(translational_stiffness=float('nan')), 'translational_stiffness'),
    (lambda: SensorModel(force_bias=(0.0, 1.0)), 'force_bias'),
])
def test_a_bad_setting_is_a_value_error_naming_it(make, name):
    with pytest.raises(ValueError, match=name):
        make().checked()


# The box doc/arm-sim.md suggests for the bridge's workspace, its corners above the table top.
WORKSPACE_CORNERS = [(x, y, z) for x in (0.2, 0.5) for y in (-0.3, 0.3) for z in (0.41, 0.55)]


@pytest.mark.slow
def test_the_suggested_workspace_is_within_reach_hand_down(fresh):
    quaternion = fresh.tool_quaternion()
    for corner in WORKSPACE_CORNERS:
        fresh.reset(HOME)
        start = fresh.tool_position()
        distance = np.linalg.norm(np.subtract(corner, start))
        steps = int(distance / 0.25 / 0.001) + 1  # at the bridge's default 0.25 m/s
        for step in range(steps + 2000):
            target = start + (np.subtract(corner, start)) * min(step / steps, 1.0)
            assert fresh.command_pose(target, quaternion, fresh.time) is None
            fresh.step()
        assert np.linalg.norm(fresh.tool_position() - corner) < 0.001, corner
        assert np.all(fresh.table_contact_force() == 0.0)
