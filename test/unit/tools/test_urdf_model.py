# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The package's URDFs: up to date, prefixed names, collision shapes, the paper's kinematics."""
import math

from harness import REPO
from kraft_master_driver.core import kinematics
from kraft_master_driver.tools.urdf_model import (
    arm_prefix, BASE_LINK, build_urdf, driver_names, GRIP_LENGTH, GRIP_LINK, LINKS, main,
    package_file_name, package_urdf, rotation_to_rpy, WRIST_LINK)
import numpy as np
import pytest
import yourdfpy

URDF_DIR = REPO / 'urdf'
SAMPLES = 200


def load(arm):
    """Parse the package's URDF of `arm` with yourdfpy."""
    return yourdfpy.URDF.load(str(URDF_DIR / package_file_name(arm)))


def random_thetas(rng, n):
    """Return n joint vectors inside the Table II limits (elbow bound coupled to th2)."""
    lower, upper = kinematics.joint_limits()
    thetas = rng.uniform(lower, upper, size=(n, 6))
    for theta in thetas:
        elbow_upper = kinematics.joint_limits(theta[1])[1][2]
        theta[2] = rng.uniform(lower[2], elbow_upper)
    return thetas


@pytest.mark.parametrize('arm', kinematics.ARMS)
def test_package_urdf_is_the_generators_output(arm):
    committed = (URDF_DIR / package_file_name(arm)).read_text()
    assert committed == package_urdf(arm), (
        'urdf/ is out of date: run python -m kraft_master_driver.tools.urdf_model urdf')


@pytest.mark.parametrize('arm', kinematics.ARMS)
def test_wrist_link_pose_equals_forward_kinematics(arm):
    robot, names = load(arm), driver_names(arm)
    assert robot.validate()
    assert robot.base_link == names['base_frame']
    rng = np.random.default_rng(5)
    thetas = random_thetas(rng, SAMPLES)
    expected = kinematics.forward(thetas, arm)
    for theta, transform in zip(thetas, expected):
        robot.update_cfg(dict(zip(robot.actuated_joint_names, theta)))
        np.testing.assert_allclose(
            robot.get_transform(names['wrist_frame'], names['base_frame']), transform,
            atol=1e-12)


@pytest.mark.parametrize('arm', kinematics.ARMS)
def test_grip_is_l5_beyond_the_wrist_along_the_roll_axis(arm):
    robot, prefix = load(arm), arm_prefix(arm)
    theta = random_thetas(np.random.default_rng(6), 1)[0]
    robot.update_cfg(dict(zip(robot.actuated_joint_names, theta)))
    wrist = kinematics.forward(theta, arm)
    grip = robot.get_transform(prefix + GRIP_LINK, prefix + BASE_LINK)
    np.testing.assert_allclose(grip[:3, 3], wrist[:3, 3] + GRIP_LENGTH * wrist[:3, 2],
                               atol=1e-12)


@pytest.mark.parametrize('arm', kinematics.ARMS)
def test_joints_are_the_drivers_with_table_ii_limits(arm):
    robot, prefix = load(arm), driver_names(arm)['joint_prefix']
    assert robot.actuated_joint_names == [prefix + n for n in kinematics.JOINT_NAMES]
    lower, upper = kinematics.joint_limits()
    for name, low, high in zip(robot.actuated_joint_names, lower, upper):
        limit = robot.joint_map[name].limit
        assert (limit.lower, limit.upper) == pytest.approx((low, high), abs=1e-12)
    elbow = robot.joint_map[prefix + 'elbow_pitch'].limit
    assert (math.degrees(elbow.lower), math.degrees(elbow.upper)) == pytest.approx((-135, -35))
    assert robot.joint_map[prefix + 'wrist_roll'].limit.effort == 0.0, 'the roll has no motor'
    assert robot.joint_map[prefix + 'elbow_pitch'].mimic is None, 'th3 is a free joint'


def test_the_arms_mirror_l3():
    right, left = load('right'), load('left')
    assert right.joint_map['right_elbow_pitch'].origin[2, 3] == pytest.approx(0.133)
    assert left.joint_map['left_elbow_pitch'].origin[2, 3] == pytest.approx(-0.133)


@pytest.mark.parametrize('prefix', ['', 'l_'])
def test_prefix_starts_every_link_and_joint_name(tmp_path, prefix):
    path = tmp_path / 'left.urdf'
    path.write_text(build_urdf('left', prefix))
    robot = yourdfpy.URDF.load(str(path))
    assert set(robot.link_map) == {prefix + name for name in (*LINKS, GRIP_LINK)}
    assert set(robot.joint_map) == {prefix + name for name in (*kinematics.JOINT_NAMES, 'grip')}
    theta = random_thetas(np.random.default_rng(7), 1)[0]
    robot.update_cfg(dict(zip(robot.actuated_joint_names, theta)))
    np.testing.assert_allclose(robot.get_transform(prefix + WRIST_LINK, prefix + BASE_LINK),
                               kinematics.forward(theta, 'left'), atol=1e-12)


@pytest.mark.parametrize('arm', kinematics.ARMS)
def test_every_link_shape_is_also_its_collision_geometry_and_no_inertial_is_made_up(arm):
    robot = load(arm)
    shaped = [link for link in robot.robot.links if link.visuals]
    assert len(shaped) == len(LINKS), 'every link but the grip point has a shape'
    for link in shaped:
        assert [(c.origin.tolist(), c.geometry) for c in link.collisions] == [
            (v.origin.tolist(), v.geometry) for v in link.visuals], link.name
    assert all(link.inertial is None for link in robot.robot.links)


@pytest.mark.parametrize('roll, pitch, yaw', [
    (0.3, -0.4, 1.2), (math.pi / 2, 0.0, 0.0), (0.0, -math.pi / 2, math.pi / 2),
    (0.0, math.pi / 2, -0.7)])
def test_rotation_to_rpy_round_trips_including_gimbal_lock(roll, pitch, yaw):
    def rotation(r, p, y):
        cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p),
                                  math.cos(y), math.sin(y))
        rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
        ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
        rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
        return rz @ ry @ rx

    matrix = rotation(roll, pitch, yaw)
    np.testing.assert_allclose(rotation(*rotation_to_rpy(matrix)), matrix, atol=1e-12)


def test_main_writes_both_package_files(tmp_path, capsys):
    assert main([str(tmp_path)]) == 0
    for arm in kinematics.ARMS:
        assert (tmp_path / package_file_name(arm)).read_text() == package_urdf(arm)
    capsys.readouterr()


@pytest.mark.parametrize('arguments, arm, prefix', [
    (['--arm', 'left'], 'left', 'left_'), ([], 'right', 'right_'),
    (['--arm', 'left', '--prefix', ''], 'left', ''), (['--prefix', 'r_'], 'right', 'r_')])
def test_main_prints_the_arms_urdf_with_its_prefix_by_default(capsys, arguments, arm, prefix):
    assert main(arguments) == 0
    assert capsys.readouterr().out == build_urdf(arm, prefix)
