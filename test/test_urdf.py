# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The package's URDFs: up to date, and their forward kinematics equal the paper's."""
import math

from driver_harness import REPO
from kraft_master_driver import kinematics
from kraft_master_driver.urdf_model import (
    BASE_LINK, build_urdf, GRIP_LENGTH, GRIP_LINK, main, package_file_name, rotation_to_rpy,
    WRIST_LINK)
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
    assert committed == build_urdf(arm), (
        'urdf/ is out of date: run python -m kraft_master_driver.urdf_model urdf')


@pytest.mark.parametrize('arm', kinematics.ARMS)
def test_wrist_link_pose_equals_forward_kinematics(arm):
    robot = load(arm)
    assert robot.validate()
    assert robot.base_link == BASE_LINK
    rng = np.random.default_rng(5)
    thetas = random_thetas(rng, SAMPLES)
    expected = kinematics.forward(thetas, arm)
    for theta, transform in zip(thetas, expected):
        robot.update_cfg(dict(zip(kinematics.JOINT_NAMES, theta)))
        np.testing.assert_allclose(
            robot.get_transform(WRIST_LINK, BASE_LINK), transform, atol=1e-12)


@pytest.mark.parametrize('arm', kinematics.ARMS)
def test_grip_is_l5_beyond_the_wrist_along_the_roll_axis(arm):
    robot = load(arm)
    theta = random_thetas(np.random.default_rng(6), 1)[0]
    robot.update_cfg(dict(zip(kinematics.JOINT_NAMES, theta)))
    wrist = kinematics.forward(theta, arm)
    grip = robot.get_transform(GRIP_LINK, BASE_LINK)
    np.testing.assert_allclose(grip[:3, 3], wrist[:3, 3] + GRIP_LENGTH * wrist[:3, 2],
                               atol=1e-12)


@pytest.mark.parametrize('arm', kinematics.ARMS)
def test_joints_are_the_drivers_with_table_ii_limits(arm):
    robot = load(arm)
    assert robot.actuated_joint_names == list(kinematics.JOINT_NAMES)
    lower, upper = kinematics.joint_limits()
    for name, low, high in zip(kinematics.JOINT_NAMES, lower, upper):
        limit = robot.joint_map[name].limit
        assert (limit.lower, limit.upper) == pytest.approx((low, high), abs=1e-12)
    elbow = robot.joint_map['elbow_pitch'].limit
    assert (math.degrees(elbow.lower), math.degrees(elbow.upper)) == pytest.approx((-135, -35))
    assert robot.joint_map['wrist_roll'].limit.effort == 0.0, 'the roll has no motor'


def test_the_arms_mirror_l3():
    right, left = load('right'), load('left')
    assert right.joint_map['elbow_pitch'].origin[2, 3] == pytest.approx(0.133)
    assert left.joint_map['elbow_pitch'].origin[2, 3] == pytest.approx(-0.133)


def test_joint_prefix_prefixes_every_joint(tmp_path):
    path = tmp_path / 'left.urdf'
    path.write_text(build_urdf('left', joint_prefix='left_'))
    robot = yourdfpy.URDF.load(str(path))
    assert robot.actuated_joint_names == ['left_' + n for n in kinematics.JOINT_NAMES]
    theta = random_thetas(np.random.default_rng(7), 1)[0]
    robot.update_cfg(dict(zip(robot.actuated_joint_names, theta)))
    np.testing.assert_allclose(robot.get_transform(WRIST_LINK, BASE_LINK),
                               kinematics.forward(theta, 'left'), atol=1e-12)


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
        assert (tmp_path / package_file_name(arm)).read_text() == build_urdf(arm)
    assert main(['--arm', 'left', '--joint-prefix', 'l_']) == 0
    assert capsys.readouterr().out.endswith(build_urdf('left', joint_prefix='l_'))
