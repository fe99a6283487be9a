# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Kinematics of the Kraft Master hand controller (NASA TM-104124, Williams 1991).

SI units throughout: metres, radians, newtons, newton-metres. Joint angles are the
DH angles th1..th6 of the paper; frames {0} (shoulder) and {6} (wrist). The closed
forms use the factored K terms of Appendix B, with the OCR errors mended
(see shared/spec/kinematics.md). Every function takes one joint vector (6,) or a
batch (N, 6).
"""
from collections.abc import Iterable, Sequence
import math
from typing import Literal, NamedTuple, overload, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

JOINT_NAMES = (
    'shoulder_yaw', 'shoulder_pitch', 'elbow_pitch', 'wrist_yaw', 'wrist_pitch', 'wrist_roll')
ARMS = ('right', 'left')
DRIVEN_JOINTS = 5
BATCH_CHUNK = 4096


class LinkLengths(NamedTuple):
    """Link lengths L1..L4 in metres; L3 is given positive and negated for the left arm."""

    l1: float
    l2: float
    l3: float
    l4: float


NOMINAL_LENGTHS = LinkLengths(l1=0.178, l2=0.203, l3=0.133, l4=0.084)

# Table II, degrees. The elbow's upper bound falls from -35 deg at th2 = 0 to -85 deg at
# th2 = 120 deg; linear interpolation between the two is an assumption, not the paper's.
_LIMITS_DEG = np.array([
    [-90.0, 90.0],
    [0.0, 120.0],
    [-135.0, -35.0],
    [-55.0, 55.0],
    [-20.0, 50.0],
    [-45.0, 45.0],
])
JOINT_LIMITS = np.radians(_LIMITS_DEG)
_ELBOW_UPPER_AT_TH2_MAX = math.radians(-85.0)
# The factored terms' entries: floats for one joint vector, arrays for a batch.
_Entry = TypeVar('_Entry', float, NDArray[np.float64])


def check_arm(arm: str) -> str:
    """Return `arm` if it names a known arm, else raise ValueError."""
    if arm not in ARMS:
        raise ValueError(f"unknown arm {arm!r}: expected 'right' or 'left'")
    return arm


def _signed_lengths(arm: str,
                    lengths: LinkLengths | None) -> tuple[float, float, float, float]:
    l1, l2, l3, l4 = NOMINAL_LENGTHS if lengths is None else lengths
    return l1, l2, (l3 if check_arm(arm) == 'right' else -l3), l4


def _factored_terms(
        trig: Sequence[_Entry], arm: str, lengths: LinkLengths | None,
) -> tuple[tuple[_Entry | float, ...], tuple[_Entry | float, ...]]:
    """
    Return the entries of 0T6 and 0J, row by row, from the Appendix B terms.

    Works elementwise on floats or on numpy arrays alike; constant entries stay floats.
    """
    c1, s1, c2, s2, c23, s23, c4, s4, c5, s5, c6, s6 = trig
    l1, l2, l3, l4 = _signed_lengths(arm, lengths)
    ki = c1 * c23
    kj = s1 * c23
    km = s23 * c5
    kn = s23 * s5
    k0 = s23 * s4
    k1 = s1 * s4 - ki * c4
    k2 = s1 * c4 + ki * s4
    k3 = -c1 * s4 - kj * c4
    k4 = -c1 * c4 + kj * s4
    k5 = c23 * s5 + km * c4
    k6 = c23 * c5 - kn * c4
    k7 = l2 * s23 + l4 * c23
    k8 = l2 * c23 - l4 * s23
    k9 = k7 + l1 * s2
    k10 = k8 + l1 * c2
    ka = k1 * s5 - km * c1
    kb = k3 * s5 - km * s1
    kc = -k1 * c5 - kn * c1
    kd = -k3 * c5 - kn * s1
    ke = k10 * s1 - l3 * c1
    kf = k10 * c1 + l3 * s1
    pose_entries = (
        k2 * s6 + ka * c6, -ka * s6 + k2 * c6, kc, kf,
        k4 * s6 + kb * c6, -kb * s6 + k4 * c6, kd, ke,
        k0 * s6 + k6 * c6, -k6 * s6 + k0 * c6, k5, k9,
        0.0, 0.0, 0.0, 1.0,
    )
    jacobian_entries = (
        -ke, -k9 * c1, -k7 * c1, 0.0, 0.0, 0.0,
        kf, -k9 * s1, -k7 * s1, 0.0, 0.0, 0.0,
        0.0, k10, k8, 0.0, 0.0, 0.0,
        0.0, s1, s1, -c1 * s23, k2, kc,
        0.0, -c1, -c1, -s1 * s23, k4, kd,
        1.0, 0.0, 0.0, c23, k0, k5,
    )
    return pose_entries, jacobian_entries


def _scalar_trig(theta: Iterable[float]) -> tuple[float, ...]:
    th1, th2, th3, th4, th5, th6 = theta
    th23 = th2 + th3
    return (math.cos(th1), math.sin(th1), math.cos(th2), math.sin(th2),
            math.cos(th23), math.sin(th23), math.cos(th4), math.sin(th4),
            math.cos(th5), math.sin(th5), math.cos(th6), math.sin(th6))


def _batch_trig(theta: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    # One contiguous row per angle keeps every later elementwise operation contiguous.
    angles = theta.T.copy()
    angles[2] += angles[1]
    cos, sin = np.cos(angles), np.sin(angles)
    return tuple(x for i in range(6) for x in (cos[i], sin[i]))


@overload
def _batch(
        theta: NDArray[np.float64], arm: str, lengths: LinkLengths | None,
        want_pose: Literal[True], want_jacobian: Literal[True],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...


@overload
def _batch(
        theta: NDArray[np.float64], arm: str, lengths: LinkLengths | None,
        want_pose: Literal[True], want_jacobian: Literal[False],
) -> tuple[NDArray[np.float64], None]: ...


@overload
def _batch(
        theta: NDArray[np.float64], arm: str, lengths: LinkLengths | None,
        want_pose: Literal[False], want_jacobian: Literal[True],
) -> tuple[None, NDArray[np.float64]]: ...


def _batch(
        theta: NDArray[np.float64], arm: str, lengths: LinkLengths | None, want_pose: bool,
        want_jacobian: bool,
) -> tuple[NDArray[np.float64] | None, NDArray[np.float64] | None]:
    n = theta.shape[0]
    poses = np.empty((n, 16)) if want_pose else None
    jacobians = np.empty((n, 36)) if want_jacobian else None
    for start in range(0, n, BATCH_CHUNK):
        chunk = slice(start, start + BATCH_CHUNK)
        entries_by_output = zip((poses, jacobians),
                                _factored_terms(_batch_trig(theta[chunk]), arm, lengths))
        for out, entries in entries_by_output:
            if out is not None:
                for column, value in enumerate(entries):
                    out[chunk, column] = value
    return (None if poses is None else poses.reshape(n, 4, 4),
            None if jacobians is None else jacobians.reshape(n, 6, 6))


def _as_six_vectors(values: ArrayLike, what: str = 'joint angles') -> NDArray[np.float64]:
    values = np.asarray(values, dtype=float)
    if values.shape[-1:] != (6,) or values.ndim not in (1, 2):
        raise ValueError(f'{what} must have shape (6,) or (N, 6), got {values.shape}')
    return values


def forward_and_jacobian(
        theta: ArrayLike, arm: str = 'right', lengths: LinkLengths | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """
    Return (0T6, 0J): the wrist pose and the Jacobian, sharing the factored terms.

    theta (6,) gives a 4x4 and a 6x6 array; theta (N, 6) gives (N, 4, 4) and (N, 6, 6).
    The Jacobian rows are (vx, vy, vz, wx, wy, wz) of the origin of {6} in {0}.
    """
    theta = _as_six_vectors(theta)
    if theta.ndim == 2:
        return _batch(theta, arm, lengths, True, True)
    pose_entries, jacobian_entries = _factored_terms(_scalar_trig(theta.tolist()), arm, lengths)
    return np.array(pose_entries).reshape(4, 4), np.array(jacobian_entries).reshape(6, 6)


def forward_and_jacobian_entries(
        theta: Sequence[float], arm: str = 'right', lengths: LinkLengths | None = None,
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """
    Return (0T6, 0J) of one joint vector as 16 and 36 floats, row by row.

    forward_and_jacobian without numpy for the control loop: theta is six floats, and the
    entries are the very floats the arrays of forward_and_jacobian hold.
    """
    return _factored_terms(_scalar_trig(theta), arm, lengths)


def forward(theta: ArrayLike, arm: str = 'right',
            lengths: LinkLengths | None = None) -> NDArray[np.float64]:
    """Return 0T6, the homogeneous transform of the wrist frame {6} in {0} (metres)."""
    theta = _as_six_vectors(theta)
    if theta.ndim == 2:
        return _batch(theta, arm, lengths, True, False)[0]
    return np.array(_factored_terms(_scalar_trig(theta.tolist()), arm, lengths)[0]).reshape(4, 4)


def jacobian(theta: ArrayLike, arm: str = 'right',
             lengths: LinkLengths | None = None) -> NDArray[np.float64]:
    """Return 0J, the 6x6 Jacobian of the origin of {6} expressed in {0}."""
    theta = _as_six_vectors(theta)
    if theta.ndim == 2:
        return _batch(theta, arm, lengths, False, True)[1]
    return np.array(_factored_terms(_scalar_trig(theta.tolist()), arm, lengths)[1]).reshape(6, 6)


def dh_transform(alpha: float, a: float, d: float, theta: float) -> NDArray[np.float64]:
    """Craig's modified DH link transform (Eq. 1) as a 4x4 array."""
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array([
        [ct, -st, 0.0, a],
        [st * ca, ct * ca, -sa, -d * sa],
        [st * sa, ct * sa, ca, d * ca],
        [0.0, 0.0, 0.0, 1.0],
    ])


def dh_table(
        theta: Iterable[float], arm: str = 'right', lengths: LinkLengths | None = None,
) -> tuple[tuple[float, float, float, float], ...]:
    """Rows (alpha_{i-1}, a_{i-1}, d_i, theta_i) of the DH table for one joint vector."""
    l1, l2, l3, l4 = _signed_lengths(arm, lengths)
    th1, th2, th3, th4, th5, th6 = (float(t) for t in theta)
    half_pi = math.pi / 2
    return (
        (0.0, 0.0, 0.0, th1),
        (half_pi, 0.0, 0.0, th2),
        (0.0, l1, l3, th3),
        (-half_pi, l2, l4, th4),
        (half_pi, 0.0, 0.0, th5 + half_pi),
        (half_pi, 0.0, 0.0, th6),
    )


def joint_torques(theta: ArrayLike, wrench: ArrayLike, arm: str = 'right',
                  lengths: LinkLengths | None = None) -> NDArray[np.float64]:
    """
    Return the six joint torques 0J^T F in N*m (Eq. 15).

    wrench is (fx, fy, fz, mx, my, mz) in {0}, acting at the origin of {6}, in N and N*m.
    Accepts (6,) or batches (N, 6) of both.
    """
    wrench = _as_six_vectors(wrench, 'wrench')
    torques: NDArray[np.float64] = np.einsum('...ji,...j->...i', jacobian(theta, arm, lengths),
                                             wrench)
    return torques


def actuator_torques(joint_tau: ArrayLike) -> NDArray[np.float64]:
    """Map joint torques to actuator torques: the elbow motor drives q3 = th2 + th3."""
    tau = np.array(joint_tau, dtype=float)
    tau[..., 1] = tau[..., 1] - tau[..., 2]
    return tau


def joint_torques_from_actuator(actuator_tau: ArrayLike) -> NDArray[np.float64]:
    """Inverse of actuator_torques: tau2 = tau_q2 + tau_q3, tau3 = tau_q3."""
    tau = np.array(actuator_tau, dtype=float)
    tau[..., 1] = tau[..., 1] + tau[..., 2]
    return tau


def joint_limits(
        theta2: float | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """
    Return (lower, upper) joint limits in radians, each of shape (6,).

    The elbow's upper bound depends on th2 (the four-bar coupling); with theta2 None the
    widest range is given.
    """
    lower, upper = JOINT_LIMITS[:, 0].copy(), JOINT_LIMITS[:, 1].copy()
    if theta2 is not None:
        span_fraction = np.clip(theta2 / JOINT_LIMITS[1, 1], 0.0, 1.0)
        upper[2] = upper[2] + span_fraction * (_ELBOW_UPPER_AT_TH2_MAX - upper[2])
    return lower, upper


def limit_violations(theta: ArrayLike, tolerance: float = 1e-9) -> list[str]:
    """Return one message per joint of `theta` (6,) outside its Table II range; [] if none."""
    theta = _as_six_vectors(theta)
    if theta.ndim != 1:
        raise ValueError(f'limit_violations takes one joint vector (6,), got {theta.shape}')
    lower, upper = joint_limits(theta[1])
    messages = []
    for name, value, low, high in zip(JOINT_NAMES, theta, lower, upper):
        if not low - tolerance <= value <= high + tolerance:
            messages.append(
                f'{name} at {math.degrees(value):.2f} deg is outside '
                f'[{math.degrees(low):.2f}, {math.degrees(high):.2f}] deg')
    return messages


def rotation_to_euler_zyx(
        rotation: Sequence[Sequence[float]] | NDArray[np.float64],
) -> tuple[float, float, float]:
    """Z-Y-X Euler angles (RZ, RY, RX) of a rotation matrix (Craig; RY in [-pi/2, pi/2])."""
    r = rotation
    ry = math.atan2(-r[2][0], math.hypot(r[0][0], r[1][0]))
    rz = math.atan2(r[1][0], r[0][0])
    rx = math.atan2(r[2][1], r[2][2])
    return rz, ry, rx


def pose_difference(
        t_current: ArrayLike, t_reference: ArrayLike,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """
    Section 4 difference of two poses of {A}: return (dp, w), both (3,) in {A}.

    dp = P_current - P_reference; w is the angular velocity that turns the reference
    orientation into the current one in unit time (Z-Y-X Euler rates, Eq. 8-10).
    """
    t_current = np.asarray(t_current, dtype=float)
    t_reference = np.asarray(t_reference, dtype=float)
    dp = t_current[:3, 3] - t_reference[:3, 3]
    r_ref = t_reference[:3, :3]
    rz, ry, rx = rotation_to_euler_zyx(r_ref.T @ t_current[:3, :3])
    cy, sy, cx, sx = math.cos(ry), math.sin(ry), math.cos(rx), math.sin(rx)
    w_reference = np.array([
        -rz * sy + rx,
        rz * cy * sx + ry * cx,
        rz * cy * cx - ry * sx,
    ])
    return dp, r_ref @ w_reference
