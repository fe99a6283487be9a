# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The teleoperation bridge's input checks, no ROS: each returns the input, or why it is refused.

A refusal is one line, named after the topic ('pose refused: ...'); the bridge goes to FAULT
with it. So is a tracking error: the arm measured too far from what it was commanded.
"""
import math
from typing import Optional, Sequence, Union

from kraft_master_driver.core.rotations import (
    norm, quaternion_to_rotation, QUATERNION_TOLERANCE, rotation_vector)
from kraft_master_driver.core.teleoperation_motion import Pose
from kraft_master_driver.core.teleoperation_settings import Array, Settings
import numpy as np

Floats = Union[Sequence[float], Array]


def checked_pose(what: str, frame_id: str, expected_frame: str, position: Floats,
                 quaternion: Floats, settings: Settings) -> Union[Pose, str]:
    """Return the Pose of the input `what` (a topic), or why it is refused."""
    if frame_id != expected_frame:
        return f'{what} refused: frame_id {frame_id!r} is not {expected_frame!r}'
    point = np.array(position, dtype=float)
    turn = np.array(quaternion, dtype=float)
    if not all(map(math.isfinite, (*point, *turn))):
        return f'{what} refused: not finite'
    distance, length = norm(point), norm(turn)
    if distance > settings.max_input_position:
        return (f'{what} refused: {distance:g} m from its base is beyond '
                f'max_input_position {settings.max_input_position:g} m')
    if abs(length - 1.0) > QUATERNION_TOLERANCE:
        return f'{what} refused: the orientation is not a unit quaternion (|q| = {length:g})'
    return Pose(point, quaternion_to_rotation(turn / length))


def checked_reading(frame_id: str, wrench: Floats, settings: Settings) -> Union[Array, str]:
    """Return an F/T reading's 6 values (force N, moment N*m), or why it is refused."""
    if frame_id != settings.ft_frame:
        return f'measured_cf refused: frame_id {frame_id!r} is not {settings.ft_frame!r}'
    values = np.array(wrench, dtype=float)
    if not all(map(math.isfinite, values)):
        return 'measured_cf refused: not finite'
    force, moment = norm(values[:3]), norm(values[3:])
    if force > settings.max_input_force or moment > settings.max_input_moment:
        return (f'measured_cf refused: |f| {force:g} N, |m| {moment:g} N*m beyond '
                f'max_input_force {settings.max_input_force:g} N or max_input_moment '
                f'{settings.max_input_moment:g} N*m')
    return values


def tracking_error(measured: Pose, reference: Pose, settings: Settings) -> Optional[str]:
    """Return why the arm at `measured` is too far from `reference`, or None."""
    error = norm(measured.position - reference.position)
    angle = norm(rotation_vector(reference.rotation @ measured.rotation.T))
    if error > settings.max_tracking_error:
        return (f'tracking error {error:.4f} m beyond max_tracking_error '
                f'{settings.max_tracking_error:g} m')
    if settings.orientation != 'ignore' and angle > settings.max_tracking_angle:
        return (f'tracking error {angle:.3f} rad beyond max_tracking_angle '
                f'{settings.max_tracking_angle:g} rad')
    return None
