# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Closed-form kinematics against the paper, the DH chain, finite differences and virtual work."""
import math

from kraft_master_driver.core import kinematics, rotations
from kraft_master_driver.core.calibration import ArmCalibration
import numpy as np
import pytest

ARMS = ('right', 'left')
MM = 1000.0
# Section 8 of the paper (right arm, nominal lengths, mm): pot counts, joint angles in degrees,
# 0T6 rows and 0J rows.
EXAMPLES = (
    {
        'pots': (2086, 2683, 992, 1595, 1715, 2025),
        'theta_deg': (0.0, 90.0, -90.0, 0.0, 0.0, 0.0),
        'pose': ((0, 0, 1, 203), (0, -1, 0, -133), (1, 0, 0, 262)),
        'jacobian': ((133, -262, -84, 0, 0, 0), (203, 0, 0, 0, 0, 0), (0, 203, 203, 0, 0, 0),
                     (0, 0, 0, 0, 0, 1), (0, -1, -1, 0, -1, 0), (1, 0, 0, 1, 0, 0)),
    },
    {
        'pots': (2622, 1610, 2268, 1829, 2488, 1745),
        'theta_deg': (-25.0, 40.0, -100.0, -35.0, 10.0, 20.0),
        'pose': ((0.498, -0.826, 0.263, 225.293), (-0.438, -0.502, -0.746, -251.805),
                 (0.748, 0.256, -0.612, -19.387)),
        'jacobian': ((251.805, 17.571, 121.267, 0, 0, 0), (225.293, -8.193, -56.548, 0, 0, 0),
                     (0, 310.602, 174.246, 0, 0, 0), (0, -0.423, -0.423, 0.785, -0.606, 0.263),
                     (0, -0.906, -0.906, -0.366, -0.621, -0.746),
                     (1, 0, 0, 0.500, 0.497, -0.612)),
    },
)
MIRROR = np.diag([1.0, -1.0, 1.0, 1.0])
# Joint signs that take a right-arm posture to its mirror image on the left arm.
MIRROR_JOINT_SIGNS = np.array([-1.0, 1.0, 1.0, -1.0, 1.0, -1.0])


def random_joints(rng, count):
    """Return joint vectors spread over and beyond the Table II ranges."""
    return rng.uniform(-math.pi, math.pi, (count, 6))


def random_lengths(rng):
    """Return link lengths of a hypothetical unit, 5 to 30 cm each."""
    return kinematics.LinkLengths(*rng.uniform(0.05, 0.3, 4))


def length_cases():
    """Return nominal lengths and two seeded random ones."""
    rng = np.random.default_rng(7)
    return [None] + [random_lengths(rng) for _ in range(2)]


def dh_chain(theta, arm, lengths):
    """Return 0T6 as the product of the six DH link transforms."""
    transform = np.eye(4)
    for alpha, a, d, angle in kinematics.dh_table(theta, arm, lengths):
        transform = transform @ kinematics.dh_transform(alpha, a, d, angle)
    return transform


def rot_x(angle):
    """Return the rotation about x."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle):
    """Return the rotation about y."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle):
    """Return the rotation about z."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def homogeneous(rotation=None, translation=(0.0, 0.0, 0.0)):
    """Return a 4x4 transform from a rotation (default none) and a translation."""
    transform = np.eye(4)
    if rotation is not None:
        transform[:3, :3] = rotation
    transform[:3, 3] = translation
    return transform


def quaternion_matrix(x, y, z, w):
    """Return the rotation matrix of a unit quaternion (x, y, z, w)."""
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def vee(skew):
    """Return the vector of a skew-symmetric 3x3 matrix, batched over leading axes."""
    return np.stack((skew[..., 2, 1], skew[..., 0, 2], skew[..., 1, 0]), axis=-1)


def in_mm(pose, jacobian):
    """Return pose and Jacobian with lengths in mm, as the paper prints them."""
    pose, jacobian = pose.copy(), jacobian.copy()
    pose[:3, 3] *= MM
    jacobian[:3] *= MM
    return pose, jacobian


def assert_matches_paper(pose, jacobian, example, length_tol, unitless_tol):
    """Compare with the paper's printed example: lengths in mm, the rest unitless."""
    pose, jacobian = in_mm(pose, jacobian)
    np.testing.assert_allclose(pose[:3, 3], np.array(example['pose'])[:, 3], atol=length_tol)
    np.testing.assert_allclose(pose[:3, :3], np.array(example['pose'])[:, :3], atol=unitless_tol)
    np.testing.assert_array_equal(pose[3], [0.0, 0.0, 0.0, 1.0])
    expected = np.array(example['jacobian'], dtype=float)
    np.testing.assert_allclose(jacobian[:3], expected[:3], atol=length_tol)
    np.testing.assert_allclose(jacobian[3:], expected[3:], atol=unitless_tol)


@pytest.mark.parametrize('example', EXAMPLES, ids=('example1', 'example2'))
def test_section8_examples_from_pot_counts(example):
    theta = ArmCalibration.nominal('right').pots_to_joints(example['pots'])
    np.testing.assert_allclose(np.degrees(theta), example['theta_deg'], atol=0.05)
    pose, jacobian = kinematics.forward_and_jacobian(theta, 'right')
    assert_matches_paper(pose, jacobian, example, length_tol=0.2, unitless_tol=1e-3)


@pytest.mark.parametrize('example', EXAMPLES, ids=('example1', 'example2'))
def test_section8_examples_from_exact_angles(example):
    theta = np.radians(example['theta_deg'])
    pose, jacobian = kinematics.forward_and_jacobian(theta, 'right')
    # The paper prints three decimals: lengths to 1e-3 mm, the rest to its rounding.
    assert_matches_paper(pose, jacobian, example, length_tol=1e-3, unitless_tol=6e-4)
    np.testing.assert_array_equal(kinematics.forward(theta), pose)
    np.testing.assert_array_equal(kinematics.jacobian(theta), jacobian)


def test_dh_transform_is_craig_modified_convention():
    rng = np.random.default_rng(1)
    for alpha, a, d, theta in rng.uniform(-3.0, 3.0, (50, 4)):
        expected = (homogeneous(rot_x(alpha)) @ homogeneous(translation=(a, 0.0, 0.0))
                    @ homogeneous(rot_z(theta)) @ homogeneous(translation=(0.0, 0.0, d)))
        np.testing.assert_allclose(
            kinematics.dh_transform(alpha, a, d, theta), expected, atol=1e-15)


@pytest.mark.parametrize('arm, d3_sign', (('right', 1.0), ('left', -1.0)))
def test_dh_table_rows(arm, d3_sign):
    theta = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    lengths = kinematics.LinkLengths(1.0, 2.0, 3.0, 4.0)
    half_pi = math.pi / 2
    expected = (
        (0.0, 0.0, 0.0, 0.1),
        (half_pi, 0.0, 0.0, 0.2),
        (0.0, 1.0, 3.0 * d3_sign, 0.3),
        (-half_pi, 2.0, 4.0, 0.4),
        (half_pi, 0.0, 0.0, 0.5 + half_pi),
        (half_pi, 0.0, 0.0, 0.6),
    )
    np.testing.assert_allclose(kinematics.dh_table(theta, arm, lengths), expected, atol=1e-15)
    nominal = kinematics.dh_table(theta, arm)
    assert nominal[2][1:3] == (0.178, 0.133 * d3_sign)
    assert nominal[3][1:3] == (0.203, 0.084)


@pytest.mark.parametrize('arm', ARMS)
@pytest.mark.parametrize('lengths', length_cases(), ids=('nominal', 'random1', 'random2'))
def test_closed_form_equals_dh_product(arm, lengths):
    thetas = random_joints(np.random.default_rng(2), 700)
    poses = kinematics.forward(thetas, arm, lengths)
    for theta, pose in zip(thetas, poses):
        np.testing.assert_allclose(pose, dh_chain(theta, arm, lengths), atol=1e-12)


@pytest.mark.parametrize('arm', ARMS)
@pytest.mark.parametrize('lengths', length_cases(), ids=('nominal', 'random1', 'random2'))
def test_jacobian_equals_finite_differences(arm, lengths):
    thetas = random_joints(np.random.default_rng(3), 2000)
    step = 1e-6
    numeric = np.empty((len(thetas), 6, 6))
    rotation = kinematics.forward(thetas, arm, lengths)[:, :3, :3]
    for joint in range(6):
        delta = np.zeros(6)
        delta[joint] = step
        ahead = kinematics.forward(thetas + delta, arm, lengths)
        behind = kinematics.forward(thetas - delta, arm, lengths)
        numeric[:, :3, joint] = (ahead[:, :3, 3] - behind[:, :3, 3]) / (2 * step)
        rotation_rate = (ahead[:, :3, :3] - behind[:, :3, :3]) / (2 * step)
        numeric[:, 3:, joint] = vee(rotation_rate @ rotation.transpose(0, 2, 1))
    np.testing.assert_allclose(kinematics.jacobian(thetas, arm, lengths), numeric, atol=1e-8)


@pytest.mark.parametrize('arm', ARMS)
def test_left_arm_negates_l3(arm):
    rng = np.random.default_rng(4)
    thetas = random_joints(rng, 500)
    lengths = random_lengths(rng)
    sign = 1.0 if arm == 'right' else -1.0
    as_right = lengths._replace(l3=sign * lengths.l3)
    for got, want in zip(kinematics.forward_and_jacobian(thetas, arm, lengths),
                         kinematics.forward_and_jacobian(thetas, 'right', as_right)):
        np.testing.assert_array_equal(got, want)


def test_left_arm_is_the_mirror_image_of_the_right():
    thetas = random_joints(np.random.default_rng(5), 500)
    mirrored = thetas * MIRROR_JOINT_SIGNS
    right_pose, right_jacobian = kinematics.forward_and_jacobian(thetas, 'right')
    left_pose, left_jacobian = kinematics.forward_and_jacobian(mirrored, 'left')
    np.testing.assert_allclose(left_pose, MIRROR @ right_pose @ MIRROR, atol=1e-14)
    # Linear velocity reflects like a vector, angular velocity like a pseudo-vector.
    twist_mirror = np.diag([1.0, -1.0, 1.0, -1.0, 1.0, -1.0])
    np.testing.assert_allclose(
        left_jacobian, twist_mirror @ right_jacobian @ np.diag(MIRROR_JOINT_SIGNS), atol=1e-14)


@pytest.mark.parametrize('count', (
    0, 1, kinematics.BATCH_CHUNK - 1, kinematics.BATCH_CHUNK, kinematics.BATCH_CHUNK + 1,
    2 * kinematics.BATCH_CHUNK + 7))
def test_batch_equals_scalar(count):
    rng = np.random.default_rng(count)
    thetas = random_joints(rng, count)
    lengths = random_lengths(rng)
    for arm in ARMS:
        poses, jacobians = kinematics.forward_and_jacobian(thetas, arm, lengths)
        assert poses.shape == (count, 4, 4) and jacobians.shape == (count, 6, 6)
        np.testing.assert_array_equal(kinematics.forward(thetas, arm, lengths), poses)
        np.testing.assert_array_equal(kinematics.jacobian(thetas, arm, lengths), jacobians)
        scalar = [kinematics.forward_and_jacobian(theta, arm, lengths) for theta in thetas]
        scalar_poses = np.array([pose for pose, _ in scalar]).reshape(count, 4, 4)
        scalar_jacobians = np.array([jacobian for _, jacobian in scalar]).reshape(count, 6, 6)
        np.testing.assert_allclose(poses, scalar_poses, rtol=0, atol=1e-14)
        np.testing.assert_allclose(jacobians, scalar_jacobians, rtol=0, atol=1e-14)


@pytest.mark.parametrize('arm', ARMS)
def test_entries_are_the_floats_of_forward_and_jacobian(arm):
    rng = np.random.default_rng(11)
    lengths = kinematics.LinkLengths(*map(float, random_lengths(rng)))
    for theta in random_joints(rng, 300).tolist():
        pose_entries, jacobian_entries = kinematics.forward_and_jacobian_entries(
            theta, arm, lengths)
        pose, jacobian = kinematics.forward_and_jacobian(theta, arm, lengths)
        assert all(type(x) is float for x in pose_entries + jacobian_entries)
        assert list(pose_entries) == pose.ravel().tolist()
        assert list(jacobian_entries) == jacobian.ravel().tolist()


def test_accepts_lists_and_tuples():
    theta = [0.1, 0.5, -1.2, 0.3, 0.2, -0.4]
    np.testing.assert_array_equal(kinematics.forward(theta), kinematics.forward(np.array(theta)))
    np.testing.assert_array_equal(
        kinematics.jacobian([theta, theta])[1], kinematics.jacobian(tuple(theta)))


@pytest.mark.parametrize('arm', ARMS)
def test_joint_torques_are_jacobian_transpose_times_wrench(arm):
    rng = np.random.default_rng(6)
    thetas = random_joints(rng, 300)
    wrenches = rng.normal(0.0, 10.0, (300, 6))
    expected = np.einsum('nji,nj->ni', kinematics.jacobian(thetas, arm), wrenches)
    np.testing.assert_allclose(kinematics.joint_torques(thetas, wrenches, arm), expected,
                               rtol=1e-13, atol=1e-13)
    for theta, wrench, tau in zip(thetas[:20], wrenches[:20], expected[:20]):
        np.testing.assert_allclose(
            kinematics.joint_torques(theta, wrench, arm),
            kinematics.jacobian(theta, arm).T @ wrench, rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(kinematics.joint_torques(theta, wrench, arm), tau,
                                   rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize('arm', ARMS)
def test_joint_torques_satisfy_virtual_work(arm):
    rng = np.random.default_rng(8)
    thetas = random_joints(rng, 300)
    wrenches = rng.normal(0.0, 10.0, (300, 6))
    motions = rng.normal(0.0, 1.0, (300, 6))
    tau = kinematics.joint_torques(thetas, wrenches, arm)
    twists = np.einsum('nij,nj->ni', kinematics.jacobian(thetas, arm), motions)
    np.testing.assert_allclose(np.sum(tau * motions, axis=1), np.sum(wrenches * twists, axis=1),
                               rtol=1e-12, atol=1e-12)
    # The same work from a small real displacement of the wrist, without the Jacobian.
    step = 1e-7
    before = kinematics.forward(thetas, arm)
    after = kinematics.forward(thetas + step * motions, arm)
    displacement = after[:, :3, 3] - before[:, :3, 3]
    turn = vee(after[:, :3, :3] @ before[:, :3, :3].transpose(0, 2, 1))
    work = (np.sum(wrenches[:, :3] * displacement, axis=1)
            + np.sum(wrenches[:, 3:] * turn, axis=1)) / step
    np.testing.assert_allclose(np.sum(tau * motions, axis=1), work, rtol=1e-4, atol=1e-4)


def test_actuator_torques_map_elbow_to_absolute_link_angle():
    joint_tau = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    np.testing.assert_array_equal(kinematics.actuator_torques(joint_tau),
                                  [1.0, -1.0, 3.0, 4.0, 5.0, 6.0])
    np.testing.assert_array_equal(joint_tau, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    np.testing.assert_array_equal(
        kinematics.joint_torques_from_actuator([1.0, -1.0, 3.0, 4.0, 5.0, 6.0]), joint_tau)


def test_actuator_torques_inverse_and_virtual_work():
    rng = np.random.default_rng(9)
    joint_tau = rng.normal(0.0, 5.0, (400, 6))
    joint_rates = rng.normal(0.0, 1.0, (400, 6))
    actuator_tau = kinematics.actuator_torques(joint_tau)
    np.testing.assert_allclose(kinematics.joint_torques_from_actuator(actuator_tau), joint_tau,
                               rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(
        kinematics.actuator_torques(kinematics.joint_torques_from_actuator(joint_tau)),
        joint_tau, rtol=1e-15, atol=1e-15)
    # Actuator coordinates q = (th1, th2, th2 + th3, th4, th5, th6).
    actuator_rates = joint_rates.copy()
    actuator_rates[:, 2] += joint_rates[:, 1]
    np.testing.assert_allclose(np.sum(actuator_tau * actuator_rates, axis=1),
                               np.sum(joint_tau * joint_rates, axis=1), rtol=1e-12, atol=1e-12)
    for tau, expected in zip(joint_tau[:5], actuator_tau[:5]):
        np.testing.assert_array_equal(kinematics.actuator_torques(tau), expected)


def spec_euler_zyx(rotation):
    """Return Z-Y-X Euler angles by the spec's formulas (Section 4, step 2)."""
    r = rotation
    ry = math.atan2(-r[2, 0], math.sqrt(r[0, 0] ** 2 + r[1, 0] ** 2))
    cy = math.cos(ry)
    return (math.atan2(r[1, 0] / cy, r[0, 0] / cy), ry, math.atan2(r[2, 1] / cy, r[2, 2] / cy))


def test_euler_zyx_round_trip():
    rng = np.random.default_rng(10)
    for _ in range(500):
        rz, rx = rng.uniform(-math.pi, math.pi, 2)
        ry = rng.uniform(-1.5, 1.5)
        rotation = rot_z(rz) @ rot_y(ry) @ rot_x(rx)
        np.testing.assert_allclose(kinematics.rotation_to_euler_zyx(rotation), (rz, ry, rx),
                                   atol=1e-12)
        np.testing.assert_allclose(spec_euler_zyx(rotation), (rz, ry, rx), atol=1e-12)


def body_rate_of_euler_path(rz, ry, rx):
    """Return the body rate of R(t) = Rz(t rz) Ry(t ry) Rx(t rx) at t = 1."""
    def path(t):
        return rot_z(t * rz) @ rot_y(t * ry) @ rot_x(t * rx)
    step = 1e-6
    rate = (path(1 + step) - path(1 - step)) / (2 * step)
    return vee(path(1).T @ rate)


@pytest.mark.parametrize('arm', ARMS)
def test_pose_difference_against_rotation_matrices(arm):
    rng = np.random.default_rng(11)
    thetas = random_joints(rng, 400)
    poses = kinematics.forward(thetas, arm)
    for current, reference in zip(poses[:200], poses[200:]):
        dp, w = kinematics.pose_difference(current, reference)
        np.testing.assert_array_equal(dp, current[:3, 3] - reference[:3, 3])
        relative = reference[:3, :3].T @ current[:3, :3]
        rz, ry, rx = spec_euler_zyx(relative)
        np.testing.assert_allclose(rot_z(rz) @ rot_y(ry) @ rot_x(rx), relative, atol=1e-12)
        np.testing.assert_allclose(reference[:3, :3].T @ w, body_rate_of_euler_path(rz, ry, rx),
                                   atol=1e-7)


def test_pose_difference_small_rotation_is_rotation_vector():
    rng = np.random.default_rng(12)
    for _ in range(50):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = 1e-4
        skew = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        turn = np.eye(3) + math.sin(angle) * skew + (1 - math.cos(angle)) * skew @ skew
        reference = homogeneous(rot_z(rng.uniform(-3, 3)) @ rot_x(rng.uniform(-3, 3)),
                                rng.normal(size=3))
        current = homogeneous(turn @ reference[:3, :3], reference[:3, 3] + (0.1, 0.2, 0.3))
        dp, w = kinematics.pose_difference(current, reference)
        np.testing.assert_allclose(dp, (0.1, 0.2, 0.3), atol=1e-15)
        np.testing.assert_allclose(w, angle * axis, atol=10 * angle ** 2)
    dp, w = kinematics.pose_difference(reference, reference)
    np.testing.assert_array_equal(dp, np.zeros(3))
    np.testing.assert_allclose(w, np.zeros(3), atol=1e-15)


def test_pose_difference_worked_value():
    current = kinematics.forward(np.radians(EXAMPLES[1]['theta_deg']))
    reference = kinematics.forward(np.radians(EXAMPLES[0]['theta_deg']))
    dp, w = kinematics.pose_difference(current, reference)
    np.testing.assert_allclose(dp * MM, (22.293, -118.805, -281.387), atol=1e-3)
    np.testing.assert_allclose(w, (-0.3574, 0.5958, -0.9987), atol=1e-4)


def random_unit_quaternions(rng, count):
    """Return uniformly distributed unit quaternions (x, y, z, w) with w >= 0."""
    quaternions = rng.normal(size=(count, 4))
    quaternions /= np.linalg.norm(quaternions, axis=1, keepdims=True)
    return quaternions * np.where(quaternions[:, 3:] < 0, -1.0, 1.0)


def test_rotation_to_quaternion_random():
    rng = np.random.default_rng(13)
    for expected in random_unit_quaternions(rng, 2000):
        quaternion = rotations.rotation_to_quaternion(quaternion_matrix(*expected))
        np.testing.assert_allclose(quaternion, expected, atol=1e-12)
        assert math.isclose(math.fsum(q * q for q in quaternion), 1.0, abs_tol=1e-14)
    for pose in kinematics.forward(random_joints(rng, 500)):
        quaternion = rotations.rotation_to_quaternion(pose[:3, :3])
        assert quaternion[3] >= 0.0
        np.testing.assert_allclose(quaternion_matrix(*quaternion), pose[:3, :3], atol=1e-12)


@pytest.mark.parametrize('rotation, expected', (
    (np.eye(3), (0.0, 0.0, 0.0, 1.0)),
    (rot_x(3.0), (math.sin(1.5), 0.0, 0.0, math.cos(1.5))),
    (rot_y(-3.0), (0.0, -math.sin(1.5), 0.0, math.cos(1.5))),
    (rot_z(3.0), (0.0, 0.0, math.sin(1.5), math.cos(1.5))),
    (rot_x(math.pi), (1.0, 0.0, 0.0, 0.0)),
    (rot_y(math.pi), (0.0, 1.0, 0.0, 0.0)),
    (rot_z(math.pi), (0.0, 0.0, 1.0, 0.0)),
), ids=('trace', 'x', 'y', 'z', 'x_half_turn', 'y_half_turn', 'z_half_turn'))
def test_rotation_to_quaternion_branches(rotation, expected):
    quaternion = rotations.rotation_to_quaternion(rotation)
    assert quaternion[3] >= 0.0
    np.testing.assert_allclose(np.abs(quaternion), np.abs(expected), atol=1e-15)
    np.testing.assert_allclose(quaternion_matrix(*quaternion), rotation, atol=1e-15)
    assert rotations.rotation_to_quaternion(rotation.tolist()) == quaternion


def test_joint_limits_table_ii():
    lower, upper = kinematics.joint_limits()
    np.testing.assert_allclose(np.degrees(lower), (-90, 0, -135, -55, -20, -45), atol=1e-12)
    np.testing.assert_allclose(np.degrees(upper), (90, 120, -35, 55, 50, 45), atol=1e-12)


@pytest.mark.parametrize('theta2_deg, elbow_upper_deg', (
    (0.0, -35.0), (60.0, -60.0), (120.0, -85.0), (-10.0, -35.0), (130.0, -85.0)))
def test_joint_limits_elbow_coupling(theta2_deg, elbow_upper_deg):
    lower, upper = kinematics.joint_limits(math.radians(theta2_deg))
    assert math.degrees(upper[2]) == pytest.approx(elbow_upper_deg, abs=1e-12)
    assert math.degrees(lower[2]) == pytest.approx(-135.0, abs=1e-12)
    widest_lower, widest_upper = kinematics.joint_limits()
    np.testing.assert_array_equal(np.delete(upper, 2), np.delete(widest_upper, 2))
    np.testing.assert_array_equal(lower, widest_lower)


def violations(theta_deg):
    """Return limit_violations of a joint vector in degrees."""
    return kinematics.limit_violations(np.radians(theta_deg))


def test_limit_violations_inside_and_on_the_bounds():
    assert violations(EXAMPLES[0]['theta_deg']) == []
    assert violations(EXAMPLES[1]['theta_deg']) == []
    assert violations((-90, 0, -135, -55, -20, -45)) == []
    assert violations((90, 0, -35, 55, 50, 45)) == []
    assert violations((90, 120, -85, 55, 50, 45)) == []


@pytest.mark.parametrize('joint, value_deg', (
    (0, 91.0), (0, -91.0), (1, -1.0), (1, 121.0), (2, -136.0), (3, 56.0), (3, -56.0),
    (4, 51.0), (4, -21.0), (5, 46.0), (5, -46.0)))
def test_limit_violations_name_the_joint(joint, value_deg):
    theta_deg = np.array([0.0, 60.0, -90.0, 0.0, 0.0, 0.0])
    theta_deg[joint] = value_deg
    (message,) = violations(theta_deg)
    assert message.startswith(kinematics.JOINT_NAMES[joint])
    assert f'{value_deg:.2f} deg' in message


@pytest.mark.parametrize('theta2_deg, theta3_deg, violates', (
    (0.0, -36.0, False), (0.0, -34.0, True), (0.0, -136.0, True),
    (120.0, -86.0, False), (120.0, -84.0, True), (120.0, -40.0, True), (120.0, -136.0, True)))
def test_limit_violations_coupled_elbow(theta2_deg, theta3_deg, violates):
    messages = violations((0.0, theta2_deg, theta3_deg, 0.0, 0.0, 0.0))
    assert [m.split()[0] for m in messages] == (['elbow_pitch'] if violates else [])


def test_all_joints_zero_is_not_reachable():
    assert [m.split()[0] for m in violations(np.zeros(6))] == ['elbow_pitch']
    assert len(violations((100, -5, 0, 60, 60, 60))) == 6


@pytest.mark.parametrize('theta', (
    np.zeros(5), np.zeros(7), np.zeros((3, 5)), np.zeros((2, 3, 6)), np.zeros(()), [[1, 2], [3]]))
def test_bad_joint_shapes_raise(theta):
    for function in (kinematics.forward, kinematics.jacobian, kinematics.forward_and_jacobian,
                     kinematics.limit_violations):
        with pytest.raises(ValueError):
            function(theta)
    with pytest.raises(ValueError):
        kinematics.joint_torques(theta, np.zeros(6))


def test_limit_violations_needs_one_vector():
    with pytest.raises(ValueError, match=r'\(6,\)'):
        kinematics.limit_violations(np.zeros((2, 6)))


@pytest.mark.parametrize('wrench', (np.zeros(5), np.zeros((1, 7)), np.zeros((2, 3, 6))))
def test_bad_wrench_shapes_raise(wrench):
    with pytest.raises(ValueError, match='wrench'):
        kinematics.joint_torques(np.zeros(6), wrench)


@pytest.mark.parametrize('arm', ('Right', 'centre', '', None, 0))
def test_bad_arm_raises(arm):
    theta = np.radians(EXAMPLES[0]['theta_deg'])
    for function in (kinematics.forward, kinematics.jacobian, kinematics.forward_and_jacobian):
        with pytest.raises(ValueError, match='unknown arm'):
            function(theta, arm)
        with pytest.raises(ValueError, match='unknown arm'):
            function(np.stack((theta, theta)), arm)
    with pytest.raises(ValueError, match='unknown arm'):
        kinematics.dh_table(theta, arm)
    with pytest.raises(ValueError, match='unknown arm'):
        kinematics.joint_torques(theta, np.zeros(6), arm)
