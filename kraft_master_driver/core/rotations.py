# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Rotations and short vectors, no ROS: quaternions (x, y, z, w), matrices, rotation vectors.

The bridge, the simulated arms and the driver's pose share these; every quaternion is ROS's
order, x, y, z, w.
"""
from collections.abc import Iterable, Sequence
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

QUATERNION_TOLERANCE = 0.01  # |q| may differ from 1 by this much; more is refused
# A short vector as callers hold one: floats in a list or a tuple, or a numpy array.
Vector = Sequence[float] | NDArray[np.float64]


def quaternion_to_rotation(quaternion: Vector) -> NDArray[np.float64]:
    """Return the rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = quaternion
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def rpy_to_rotation(roll: float, pitch: float, yaw: float) -> NDArray[np.float64]:
    """Return Rz(yaw) Ry(pitch) Rx(roll), as ROS's roll, pitch, yaw (REP 103)."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch),
                              math.sin(pitch), math.cos(yaw), math.sin(yaw))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def norm(vector: Iterable[float]) -> float:
    """Return the length of a short vector: math.hypot, a few times faster than numpy's norm."""
    return math.hypot(*vector)


def cross(a: Vector, b: Vector) -> NDArray[np.float64]:
    """Return the cross product of two 3-vectors (numpy's takes microseconds to set up)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


def rotation_parameter(name: str, values: Iterable[float]) -> NDArray[np.float64]:
    """Return the rotation of 3 values (roll, pitch, yaw; rad) or 4 (a quaternion x, y, z, w)."""
    values = [float(v) for v in values]
    if not all(math.isfinite(v) for v in values) or len(values) not in (3, 4):
        raise ValueError(f'{name} must be 3 finite values (roll, pitch, yaw in rad) or 4 (a '
                         f'unit quaternion x, y, z, w), got {values}')
    if len(values) == 3:
        return rpy_to_rotation(*values)
    if abs(math.sqrt(sum(v * v for v in values)) - 1.0) > QUATERNION_TOLERANCE:
        raise ValueError(f'{name}: the quaternion {values} is not of unit length')
    return quaternion_to_rotation(np.array(values) / np.linalg.norm(values))


def rotation_vector(rotation: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return the axis times angle (rad, 3) of a rotation matrix, angle in [0, pi]."""
    cosine = max(-1.0, min(1.0, (np.trace(rotation) - 1.0) / 2.0))
    angle = math.acos(cosine)
    if angle < 1e-9:
        return np.zeros(3)
    axis_sin = np.array([rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0],
                         rotation[1, 0] - rotation[0, 1]]) / 2.0
    if angle < math.pi - 1e-6:
        return axis_sin * (angle / math.sin(angle))
    # Near a half turn the axis comes from the symmetric part.
    column = int(np.argmax(np.diag(rotation)))
    axis = (rotation[:, column] + np.eye(3)[:, column]) / 2.0
    return angle * axis / np.linalg.norm(axis)


def rotation_from_vector(vector: Vector) -> NDArray[np.float64]:
    """Return the rotation matrix of an axis times angle (rad, 3): Rodrigues' formula."""
    angle = norm(vector)
    if angle < 1e-12:
        return np.eye(3)
    kx, ky, kz = np.asarray(vector) / angle
    k: NDArray[np.float64] = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def clamp_norm(vector: NDArray[np.float64], limit: float) -> NDArray[np.float64]:
    """Return `vector` shortened to length `limit` if it is longer."""
    length = norm(vector)
    return vector * (limit / length) if length > limit else vector


def rotation_to_quaternion(
        rotation: Sequence[Sequence[float]] | NDArray[np.float64],
) -> tuple[float, float, float, float]:
    """Return the unit quaternion (x, y, z, w) of a rotation matrix, with w >= 0."""
    r = rotation
    r00, r01, r02 = r[0][0], r[0][1], r[0][2]
    r10, r11, r12 = r[1][0], r[1][1], r[1][2]
    r20, r21, r22 = r[2][0], r[2][1], r[2][2]
    trace = r00 + r11 + r22
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        x, y, z, w = (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s, 0.25 * s
    elif r00 > r11 and r00 > r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        x, y, z, w = 0.25 * s, (r01 + r10) / s, (r02 + r20) / s, (r21 - r12) / s
    elif r11 > r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        x, y, z, w = (r01 + r10) / s, 0.25 * s, (r12 + r21) / s, (r02 - r20) / s
    else:
        s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
        x, y, z, w = (r02 + r20) / s, (r12 + r21) / s, 0.25 * s, (r10 - r01) / s
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    length = math.sqrt(x * x + y * y + z * z + w * w)
    return x / length, y / length, z / length, w / length


def rotations_to_quaternions(rotations: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return one unit quaternion row (x, y, z, w; w >= 0) per rotation matrix of (N, 3, 3)."""
    r = rotations
    r00, r11, r22 = r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]
    trace = r00 + r11 + r22
    # The same four cases as rotation_to_quaternion, ties broken alike, per row.
    case = np.where(trace > 0.0, 3, np.where((r00 > r11) & (r00 > r22), 0,
                                             np.where(r11 > r22, 1, 2)))
    q: NDArray[np.float64] = np.empty((len(r), 4))
    with np.errstate(invalid='ignore', divide='ignore'):
        for index, rows in enumerate(case == k for k in range(4)):
            m = r[rows]
            if index == 3:
                s = 2.0 * np.sqrt(trace[rows] + 1.0)
                q[rows] = np.stack([(m[:, 2, 1] - m[:, 1, 2]) / s, (m[:, 0, 2] - m[:, 2, 0]) / s,
                                    (m[:, 1, 0] - m[:, 0, 1]) / s, 0.25 * s], axis=1)
                continue
            i, j, k = index, (index + 1) % 3, (index + 2) % 3
            s = 2.0 * np.sqrt(1.0 + m[:, i, i] - m[:, j, j] - m[:, k, k])
            q[rows, i] = 0.25 * s
            q[rows, j] = (m[:, i, j] + m[:, j, i]) / s
            q[rows, k] = (m[:, i, k] + m[:, k, i]) / s
            q[rows, 3] = (m[:, k, j] - m[:, j, k]) / s
    q[q[:, 3] < 0.0] *= -1.0
    lengths: NDArray[np.float64] = np.linalg.norm(q, axis=1, keepdims=True)
    return q / lengths


def integrate_quaternion(quaternion: Vector, angular_velocity: ArrayLike,
                         dt: float) -> tuple[float, ...]:
    """Turn a unit quaternion (x, y, z, w) by angular_velocity (rad/s, base frame) for dt s."""
    rotation = np.asarray(angular_velocity, dtype=float) * dt
    angle = math.sqrt(float(rotation @ rotation))
    if angle == 0.0:
        return tuple(quaternion)
    ux, uy, uz = rotation * (math.sin(angle / 2.0) / angle)
    uw = math.cos(angle / 2.0)
    x, y, z, w = quaternion
    turned = np.array([
        uw * x + ux * w + uy * z - uz * y,
        uw * y - ux * z + uy * w + uz * x,
        uw * z + ux * y - uy * x + uz * w,
        uw * w - ux * x - uy * y - uz * z,
    ])
    return tuple((turned / math.sqrt(float(turned @ turned))).tolist())
