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


BOX_TOLERANCE = 0.005  # m past the workspace box an arm may be and still be enabled
Sample = Optional[tuple[object, float]]  # an input and its receipt time (s), None: none yet


def enable_refusal(settings: Settings, master: Sample, arm: Optional[tuple[Pose, float]],
                   reading: Sample, box: tuple[Array, Array], now: float) -> Optional[str]:
    """Return why the bridge cannot be enabled at `now` (a stale input, the arm out of the box)."""
    inputs: list[tuple[str, Sample, float]] = [('pose', master, settings.master_timeout),
                                               ('measured_cp', arm, settings.arm_timeout)]
    if settings.force_feedback:
        inputs.append(('measured_cf', reading, settings.ft_timeout))
    missing = [name for name, sample, timeout in inputs
               if sample is None or now - sample[1] > timeout]
    if missing:
        return 'no fresh ' + ', '.join(missing) + ': not enabled'
    assert arm is not None
    position = arm[0].position
    # The target never leaves the box, but an arm held there after a FAULT may sit a little past
    # it (its impedance lags the target): refused, teleoperation could never start again.
    if (np.any(position < box[0] - BOX_TOLERANCE)
            or np.any(position > box[1] + BOX_TOLERANCE)):
        return (f'the arm at {np.round(position, 4).tolist()} m is outside the workspace box: '
                'not enabled')
    return None


def stale_arm_side(settings: Settings, arm: Sample, reading: Sample,
                   now: float) -> Optional[str]:
    """Return why the arm's side is stale at `now` (measured_cp, or measured_cf), or None."""
    if arm is None or now - arm[1] > settings.arm_timeout:
        return f'measured_cp older than arm_timeout {settings.arm_timeout:g} s'
    if settings.force_feedback and reading is not None and now - reading[1] > settings.ft_timeout:
        return f'measured_cf older than ft_timeout {settings.ft_timeout:g} s'
    return None


def arm_side_late(settings: Settings, arm: Sample, reading: Sample,
                  now: float) -> Optional[str]:
    """Return why the arm is held at `now` (its pose or reading older than arm_hold_timeout)."""
    limit = settings.arm_hold_timeout
    if arm is None or now - arm[1] > limit:
        return f'measured_cp older than arm_hold_timeout {limit:g} s'
    if settings.force_feedback and (reading is None or now - reading[1] > limit):
        return f'measured_cf older than arm_hold_timeout {limit:g} s'
    return None


def hold_reason(settings: Settings, master_time: float, arm: Sample, reading: Sample,
                now: float) -> Optional[tuple[str, bool]]:
    """
    Return why a following arm holds at `now`, and whether for its own side; or None.

    Its side late, not yet faulty (arm_hold_timeout): it may not have followed, and is held
    where it was sent, the master freed; a master pose older than master_timeout.
    """
    late = arm_side_late(settings, arm, reading, now)
    if late is not None:
        return f'holding: {late}', True
    if now - master_time > settings.master_timeout:
        return f'holding: pose older than master_timeout {settings.master_timeout:g} s', False
    return None


def tare_refusal(settings: Settings, arm: Sample, reading: Sample, now: float) -> Optional[str]:
    """Return why the F/T bias cannot be taken at `now`, or None."""
    if reading is None or now - reading[1] > settings.ft_timeout:
        return 'no fresh measured_cf to tare'
    if arm is None or now - arm[1] > settings.arm_timeout:
        return 'no fresh measured_cp: the tool weight needs the orientation'
    return None
