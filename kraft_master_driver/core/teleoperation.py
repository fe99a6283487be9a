# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The teleoperation bridge's logic, no ROS: master pose -> arm target, arm F/T -> master wrench.

Teleoperation runs one master/arm pair through four operating states:

- DISABLED: nothing is sent to the arm; the master gets zero wrench. enable() leaves it.
- ENABLED: the arm's target follows the master. The offset between them is taken anew
  (registration) at enable, at every clutch release and when a stale master pose comes back,
  so the target starts exactly where the arm is held and never jumps.
- CLUTCHED: the arm holds, the master is free (zero wrench) and may be moved anywhere.
- FAULT: an input was refused, went stale or the arm left its command; the arm holds where it
  was measured, the master gets zero wrench, and only enable() leaves it.

Frames: the master's pose is in the master's base frame, the arm's pose and its target in the
arm's base frame; `base_rotation` turns master-base vectors into arm-base ones. The wrist F/T
reading is the wrench the tool applies to the sensor, in the sensor's frame (`sensor_rotation`
from the arm's measured tool frame). Times are monotonic seconds given by the caller.
"""
import math
from typing import NamedTuple

from kraft_master_driver.core.passivity import SlavePort
from kraft_master_driver.core.rotations import (
    clamp_norm, cross, norm, quaternion_to_rotation, QUATERNION_TOLERANCE, rotation_from_vector,
    rotation_parameter, rotation_to_quaternion, rotation_vector)
import numpy as np

STATES = ('DISABLED', 'ENABLED', 'CLUTCHED', 'FAULT')
ORIENTATIONS = ('follow', 'fixed', 'ignore')
MAX_STEP = 0.05  # s: a longer gap between two master poses is taken as this long


def _dead_band(vector, band):
    """Shrink a vector's length by `band`, to zero below it: no step at its edge."""
    length = norm(vector)
    return vector * (max(length - band, 0.0) / length) if length > 0.0 else vector


class Pose(NamedTuple):
    """A position (m, 3) and a rotation matrix (3x3), in one base frame."""

    position: np.ndarray
    rotation: np.ndarray

    @property
    def quaternion(self):
        """Return the orientation: the unit quaternion x, y, z, w."""
        return rotation_to_quaternion(self.rotation)


class Settings(NamedTuple):
    """What the bridge is told: mapping, limits, timeouts and the force path (SI units)."""

    scale: float = 1.0
    orientation: str = 'follow'
    base_rotation: tuple = (0.0, 0.0, 0.0)  # master base -> arm base: rpy or quaternion
    sensor_rotation: tuple = (0.0, 0.0, 0.0)  # sensor frame in the arm's measured tool frame
    master_frame: str = 'kraft_master_base'
    arm_frame: str = 'base_link'
    ft_frame: str = 'ft_sensor'
    workspace_min: tuple = (-2.0, -2.0, -2.0)
    workspace_max: tuple = (2.0, 2.0, 2.0)
    max_linear_speed: float = 0.25  # m/s of the target
    max_angular_speed: float = 1.0  # rad/s of the target
    twist_gain: float = 10.0  # 1/s, twist mode: command = gain * (target - measured)
    master_timeout: float = 0.1
    arm_timeout: float = 0.1
    ft_timeout: float = 0.1
    max_tracking_error: float = 0.05  # m between the command and the measured arm
    max_tracking_angle: float = 0.5  # rad
    force_feedback: bool = True
    tool_mass: float = 0.0
    tool_com: tuple = (0.0, 0.0, 0.0)  # m, sensor frame
    gravity: tuple = (0.0, 0.0, -9.81)  # m/s^2, arm base frame
    force_scale: float = 1.0
    moment_scale: float = 1.0
    force_deadband: float = 0.0
    moment_deadband: float = 0.0
    force_cutoff_hz: float = 0.0  # 0: no low-pass
    max_force: float = 10.0  # N, of the master's wrench
    max_moment: float = 1.0  # N*m
    max_input_force: float = 1000.0  # N: a larger F/T reading is refused
    max_input_moment: float = 100.0  # N*m
    max_input_position: float = 10.0  # m: a pose farther from its base is refused
    passivity: bool = False
    drift_gain: float = 2.0


class Teleoperation:
    """
    One master/arm pair: feed it the inputs as they come, ask it what to send.

    Every input method returns None when it took the input, else the one line that says why
    it was refused (the state is then FAULT with that reason).
    """

    def __init__(self, settings=Settings()):
        """Check the settings (ValueError naming the bad one); start DISABLED."""
        self.settings = settings
        if settings.orientation not in ORIENTATIONS:
            raise ValueError(f'orientation must be one of {", ".join(ORIENTATIONS)}, '
                             f'got {settings.orientation!r}')
        self.base_rotation = rotation_parameter('base_rotation', settings.base_rotation)
        self.sensor_rotation = rotation_parameter('sensor_rotation', settings.sensor_rotation)
        self.box = (np.array(settings.workspace_min, dtype=float),
                    np.array(settings.workspace_max, dtype=float))
        if self.box[0].shape != (3,) or not np.all(self.box[0] < self.box[1]):
            raise ValueError('workspace_min must be below workspace_max on every axis, got '
                             f'{list(settings.workspace_min)} and {list(settings.workspace_max)}')
        for name in ('tool_com', 'gravity'):
            values = np.array(getattr(settings, name), dtype=float)
            if values.shape != (3,) or not np.all(np.isfinite(values)):
                raise ValueError(f'{name} must be 3 finite numbers, got '
                                 f'{list(getattr(settings, name))}')
        self.port = SlavePort(settings.drift_gain)
        self.port.enabled = settings.passivity
        self.state = 'DISABLED'
        self.reason = 'not enabled'
        self.clutch_pressed = False
        self.bias = np.zeros(6)
        self.master = None  # (Pose, receipt time)
        self.arm = None
        self.reading = None  # (6 floats in the sensor frame, receipt time)
        self.hold = None  # the pose the arm holds while not following
        self.command = None  # the last pose commanded while following
        self._target = None  # the speed-limited target, before the passivity port
        self._registration = None  # (master pose, arm pose) at the last registration
        self._filtered = np.zeros(6)
        self._filtered_at = None

    # -- state -------------------------------------------------------------------------

    @property
    def following(self):
        """Whether the arm follows the master now (ENABLED and registered)."""
        return self.state == 'ENABLED' and self._registration is not None

    def describe(self):
        """Return the state as operating_state shows it: 'STATE: reason'."""
        return f'{self.state}: {self.reason}' if self.reason else self.state

    def _fault(self, reason, now):
        """Go to FAULT: an arm that was driven holds where measured if fresh, else commanded."""
        if self.state in ('ENABLED', 'CLUTCHED'):
            arm_fresh = self.arm is not None and now - self.arm[1] <= self.settings.arm_timeout
            if arm_fresh:
                self.hold = self.arm[0]
            elif self.command is not None:
                self.hold = self.command
        self.state, self.reason = 'FAULT', reason
        self._registration = None
        return reason

    def _hold_here(self):
        """Hold at the last command (or where the arm is, if nothing was commanded yet)."""
        if self.command is not None:
            self.hold = self.command
        self._registration = None

    def enable(self, now):
        """Enable (or re-enable after a fault); return None, or why not (state unchanged)."""
        settings = self.settings
        inputs = [('pose', self.master, settings.master_timeout),
                  ('measured_cp', self.arm, settings.arm_timeout)]
        if settings.force_feedback:
            inputs.append(('measured_cf', self.reading, settings.ft_timeout))
        missing = [name for name, sample, timeout in inputs
                   if sample is None or now - sample[1] > timeout]
        if missing:
            return 'no fresh ' + ', '.join(missing) + ': not enabled'
        position = self.arm[0].position
        if np.any(position < self.box[0]) or np.any(position > self.box[1]):
            return (f'the arm at {np.round(position, 4).tolist()} m is outside the workspace '
                    'box: not enabled')
        if self.state in ('ENABLED', 'CLUTCHED'):
            return None
        # Registered at the next master pose: the arm's target starts where it is.
        self.command, self.hold, self._registration = None, self.arm[0], None
        self.state, self.reason = 'CLUTCHED' if self.clutch_pressed else 'ENABLED', ''
        return None

    def set_base_rotation(self, quaternion):
        """Take base_rotation anew (x, y, z, w) while not driving the arm; return why not."""
        if self.state in ('ENABLED', 'CLUTCHED'):
            return 'base_rotation is fixed while enabled'
        try:
            self.base_rotation = rotation_parameter('base_rotation', quaternion)
        except ValueError as error:
            return str(error)
        return None

    def disable(self):
        """Stop: nothing more is sent to the arm."""
        self.state, self.reason = 'DISABLED', 'disabled'
        self._registration = None
        self.hold = self.command = None

    def set_clutch(self, pressed):
        """Press or release the clutch: hold while pressed, register anew on release."""
        if pressed == self.clutch_pressed:
            return
        self.clutch_pressed = pressed
        if pressed and self.state == 'ENABLED':
            self._hold_here()
            self.state, self.reason = 'CLUTCHED', ''
        elif not pressed and self.state == 'CLUTCHED':
            self.state = 'ENABLED'  # registered at the next master pose

    def _register(self):
        """Take the offset anew: the master's current pose maps to the pose held now."""
        self._registration = (self.master[0], self.hold)
        self._target = self.hold
        self.command = self.hold
        self.port.reset(self.hold.position.tolist())

    def check(self, now):
        """Apply the timeouts at `now`: a stale master holds, a stale arm or F/T is a FAULT."""
        settings = self.settings
        if self.state not in ('ENABLED', 'CLUTCHED'):
            return
        if now - self.arm[1] > settings.arm_timeout:
            self._fault(f'measured_cp older than arm_timeout {settings.arm_timeout:g} s', now)
        elif settings.force_feedback and now - self.reading[1] > settings.ft_timeout:
            self._fault(f'measured_cf older than ft_timeout {settings.ft_timeout:g} s', now)
        elif self.following and now - self.master[1] > settings.master_timeout:
            self._hold_here()
            self.reason = f'holding: pose older than master_timeout {settings.master_timeout:g} s'

    # -- inputs ------------------------------------------------------------------------

    def _checked_pose(self, what, frame_id, expected_frame, position, quaternion, now):
        """Return (Pose, None) of a pose input, or (None, why it is refused)."""
        if frame_id != expected_frame:
            return None, self._fault(f'{what} refused: frame_id {frame_id!r} is not '
                                     f'{expected_frame!r}', now)
        position = np.array(position, dtype=float)
        quaternion = np.array(quaternion, dtype=float)
        if not all(map(math.isfinite, (*position, *quaternion))):
            return None, self._fault(f'{what} refused: not finite', now)
        distance, length = norm(position), norm(quaternion)
        if distance > self.settings.max_input_position:
            return None, self._fault(
                f'{what} refused: {distance:g} m from its base is beyond '
                f'max_input_position {self.settings.max_input_position:g} m', now)
        if abs(length - 1.0) > QUATERNION_TOLERANCE:
            return None, self._fault(f'{what} refused: the orientation is not a unit '
                                     f'quaternion (|q| = {length:g})', now)
        rotation = quaternion_to_rotation(quaternion / length)
        return Pose(position, rotation), None

    def master_pose(self, frame_id, position, quaternion, now):
        """Take the master's wrist pose (master base frame); registers if not registered."""
        pose, refused = self._checked_pose('pose', frame_id, self.settings.master_frame,
                                           position, quaternion, now)
        if refused:
            return refused
        previous = self.master
        self.master = (pose, now)
        if self.state != 'ENABLED':
            return None
        if self._registration is None:
            self.reason = ''
            self._register()
            return None
        dt = min(now - previous[1], MAX_STEP)
        self._follow(pose, dt)
        return None

    def arm_pose(self, frame_id, position, quaternion, now):
        """Take the arm's measured tool pose (arm base frame); check the tracking error."""
        pose, refused = self._checked_pose('measured_cp', frame_id, self.settings.arm_frame,
                                           position, quaternion, now)
        if refused:
            return refused
        self.arm = (pose, now)
        reference = self.command if self.following else self.hold
        if self.state in ('ENABLED', 'CLUTCHED') and reference is not None:
            error = norm(pose.position - reference.position)
            angle = norm(rotation_vector(reference.rotation @ pose.rotation.T))
            settings = self.settings
            if error > settings.max_tracking_error:
                return self._fault(f'tracking error {error:.4f} m beyond max_tracking_error '
                                   f'{settings.max_tracking_error:g} m', now)
            if settings.orientation != 'ignore' and angle > settings.max_tracking_angle:
                return self._fault(f'tracking error {angle:.3f} rad beyond '
                                   f'max_tracking_angle {settings.max_tracking_angle:g} rad',
                                   now)
        return None

    def ft_reading(self, frame_id, wrench, now):
        """Take one F/T reading (force N, moment N*m, sensor frame)."""
        settings = self.settings
        if frame_id != settings.ft_frame:
            return self._fault(f'measured_cf refused: frame_id {frame_id!r} is not '
                               f'{settings.ft_frame!r}', now)
        wrench = np.array(wrench, dtype=float)
        if not all(map(math.isfinite, wrench)):
            return self._fault('measured_cf refused: not finite', now)
        force, moment = norm(wrench[:3]), norm(wrench[3:])
        if force > settings.max_input_force or moment > settings.max_input_moment:
            return self._fault(
                f'measured_cf refused: |f| {force:g} N, |m| {moment:g} N*m beyond '
                f'max_input_force {settings.max_input_force:g} N or max_input_moment '
                f'{settings.max_input_moment:g} N*m', now)
        self.reading = (wrench, now)
        return None

    def master_energy(self, energy_in):
        """Take the master port's energy in (J): the slave port's credit."""
        self.port.credit(energy_in)

    def tare(self, now):
        """Take the current reading, less the tool's weight, as the bias; None or why not."""
        if self.reading is None or now - self.reading[1] > self.settings.ft_timeout:
            return 'no fresh measured_cf to tare'
        if self.arm is None or now - self.arm[1] > self.settings.arm_timeout:
            return 'no fresh measured_cp: the tool weight needs the orientation'
        self.bias = self.reading[0] - self._tool_weight()
        self._filtered = np.zeros(6)
        return None

    # -- the motion path ---------------------------------------------------------------

    def _mapped(self, pose):
        """Return the arm target of a master pose through the registration."""
        master0, arm0 = self._registration
        rotation = self.base_rotation
        position = arm0.position + self.settings.scale * (
            rotation @ (pose.position - master0.position))
        if self.settings.orientation == 'follow':
            turn = rotation @ pose.rotation @ master0.rotation.T @ rotation.T
            orientation = turn @ arm0.rotation
        else:
            orientation = arm0.rotation
        return Pose(np.clip(position, *self.box), orientation)

    def _follow(self, pose, dt):
        """Move the target toward the mapped master pose within the speed limits."""
        wanted = self._mapped(pose)
        settings = self.settings
        step = clamp_norm(wanted.position - self._target.position, settings.max_linear_speed * dt)
        turn = clamp_norm(rotation_vector(wanted.rotation @ self._target.rotation.T),
                          settings.max_angular_speed * dt)
        self._target = Pose(self._target.position + step,
                            rotation_from_vector(turn) @ self._target.rotation)
        force = self._environment_force() if settings.force_feedback else np.zeros(3)
        position = self.port.step(self._target.position.tolist(), force.tolist(), dt)
        self.command = Pose(np.array(position), self._target.rotation)

    def arm_command(self):
        """Return the pose the arm should be at now, or None (DISABLED: send nothing)."""
        if self.state == 'DISABLED':
            return None
        pose = self.command if self.following else self.hold
        if pose is not None and self.settings.orientation == 'ignore' and self.arm is not None:
            return Pose(pose.position, self.arm[0].rotation)
        return pose

    def arm_twist(self):
        """Return the twist command (6: m/s, rad/s, arm base), zeros unless following."""
        if not self.following or self.arm is None:
            return np.zeros(6)
        settings = self.settings
        measured = self.arm[0]
        linear = clamp_norm(settings.twist_gain * (self.command.position - measured.position),
                            settings.max_linear_speed)
        angular = np.zeros(3)
        if settings.orientation != 'ignore':
            angular = clamp_norm(settings.twist_gain * rotation_vector(
                self.command.rotation @ measured.rotation.T), settings.max_angular_speed)
        return np.concatenate([linear, angular])

    # -- the force path ----------------------------------------------------------------

    def _sensor_in_base(self):
        return self.arm[0].rotation @ self.sensor_rotation

    def _tool_weight(self):
        """Return the wrench (6, sensor frame) the tool's weight puts on the sensor."""
        settings = self.settings
        force = settings.tool_mass * (self._sensor_in_base().T @ np.array(settings.gravity))
        return np.concatenate([force, cross(settings.tool_com, force)])

    def contact_wrench(self):
        """Return the environment's wrench on the tool (6, arm base frame), less bias and tool."""
        wrench = self.reading[0] - self.bias - self._tool_weight()
        rotation = self._sensor_in_base()
        return np.concatenate([rotation @ wrench[:3], rotation @ wrench[3:]])

    def _environment_force(self):
        if self.reading is None or self.arm is None:
            return np.zeros(3)
        return self.contact_wrench()[:3]

    def master_wrench(self, now):
        """Return the wrench for the master (6, master base frame); zeros unless following."""
        if not (self.following and self.settings.force_feedback and self.reading is not None):
            self._filtered, self._filtered_at = np.zeros(6), None
            return np.zeros(6)
        settings = self.settings
        contact = self.contact_wrench()
        back = self.base_rotation.T
        force = _dead_band(settings.force_scale * (back @ contact[:3]), settings.force_deadband)
        moment = _dead_band(settings.moment_scale * (back @ contact[3:]),
                            settings.moment_deadband)
        wrench = np.concatenate([force, moment])
        if settings.force_cutoff_hz > 0.0 and self._filtered_at is not None:
            dt = min(max(now - self._filtered_at, 0.0), MAX_STEP)
            alpha = 1.0 - math.exp(-2.0 * math.pi * settings.force_cutoff_hz * dt)
            wrench = self._filtered + alpha * (wrench - self._filtered)
        self._filtered, self._filtered_at = wrench, now
        return np.concatenate([clamp_norm(wrench[:3], settings.max_force),
                               clamp_norm(wrench[3:], settings.max_moment)])
