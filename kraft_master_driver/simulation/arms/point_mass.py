# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The point-mass arm behind kraft_master_slave_sim, no ROS: a servoed tool point, a wall, a box.

The arm is a point mass (its tool point) servoed toward a target with velocity and
acceleration limits, in an environment with a stiff virtual wall and a soft box. ArmServo is
what the arm does with its commands: follow the newest while fresh, else hold still.
nodes/slave_sim.py runs it behind the bridge's arm-side topics.
"""
import math
from typing import NamedTuple

from kraft_master_driver.core.rotations import (
    clamp_norm, integrate_quaternion, quaternion_to_rotation, QUATERNION_TOLERANCE)
import numpy as np

MODES = ('pose', 'twist')
MAX_STEP = 0.002  # s, longest integration step
MAX_CATCH_UP = 0.1  # s of simulated time per advance(); a longer stall is skipped, not replayed


def _vector(name, values):
    """Return `values` as a float array of 3 finite numbers, else raise ValueError."""
    try:
        array = np.array(values, dtype=float)
    except (TypeError, ValueError):
        array = None
    if array is None or array.shape != (3,) or not np.all(np.isfinite(array)):
        raise ValueError(f'{name} must be 3 finite numbers, got {values!r}')
    return array


def checked_number(name, value, positive=False):
    """Return `value` as a finite float >= 0 (> 0 if positive), else raise ValueError."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f'{name} must be a number, got {value!r}')
    if not (math.isfinite(value) and (value > 0.0 if positive else value >= 0.0)):
        raise ValueError(f'{name} must be finite and {">" if positive else ">="} 0, got {value}')
    return float(value)


def _push(normal, depth, velocity, stiffness, damping):
    """Spring-damper force (N) along a unit `normal` at `depth` (m), never pulling."""
    rate = -float(velocity @ normal)
    return max(stiffness * depth + damping * rate, 0.0) * normal


class Wall:
    """A stiff plane through `point`; free space lies on the side `normal` points to."""

    def __init__(self, point, normal, stiffness, damping):
        """Check the plane (m), stiffness (N/m) and damping (N*s/m); the normal is normalised."""
        self.point = _vector('wall.point', point)
        normal = _vector('wall.normal', normal)
        length = math.sqrt(float(normal @ normal))
        if length == 0.0:
            raise ValueError('wall.normal must not be zero')
        self.normal = normal / length
        self.stiffness = checked_number('wall.stiffness', stiffness)
        self.damping = checked_number('wall.damping', damping)

    def penetration(self, position):
        """Return how deep (m) `position` is behind the surface; negative in free space."""
        return float((self.point - position) @ self.normal)

    def force(self, position, velocity):
        """Force (N) on a point: k * depth + b * depth rate along the normal, never pulling."""
        depth = self.penetration(position)
        if depth <= 0.0:
            return np.zeros(3)
        return _push(self.normal, depth, velocity, self.stiffness, self.damping)


class SoftBox:
    """A soft box: a point inside is pushed out through the nearest face, like the wall's."""

    def __init__(self, centre, half_sizes, stiffness, damping):
        """Check the centre (m), half sizes (m, > 0), stiffness (N/m) and damping (N*s/m)."""
        self.centre = _vector('box.centre', centre)
        self.half_sizes = _vector('box.half_sizes', half_sizes)
        if not np.all(self.half_sizes > 0.0):
            raise ValueError(f'box.half_sizes must be > 0, got {self.half_sizes.tolist()}')
        self.stiffness = checked_number('box.stiffness', stiffness)
        self.damping = checked_number('box.damping', damping)

    def force(self, position, velocity):
        """Force (N) on a point at `position` moving at `velocity`; zero outside the box."""
        offset = position - self.centre
        depth = self.half_sizes - np.abs(offset)
        if not np.all(depth > 0.0):
            return np.zeros(3)
        axis = int(np.argmin(depth))
        normal = np.zeros(3)
        normal[axis] = math.copysign(1.0, offset[axis])
        return _push(normal, float(depth[axis]), velocity, self.stiffness, self.damping)


class SlaveLimits(NamedTuple):
    """The slave's servo: limits (m/s, m/s^2), moving mass (kg) and loop gains (1/s)."""

    max_velocity: float = 0.25  # ISO 10218-1's reduced speed for manual mode
    max_acceleration: float = 5.0  # with the mass, the largest force the slave can push with
    mass: float = 1.0
    position_gain: float = 15.0
    velocity_gain: float = 60.0  # 4 * position_gain: the cascade is critically damped

    def checked(self):
        """Return the limits with every value a positive finite float, else raise ValueError."""
        return SlaveLimits(*(checked_number(name, value, positive=True)
                             for name, value in zip(self._fields, self)))


class SlaveArm:
    """
    The slave's wrist point: a mass driven by a velocity-limited, force-limited servo.

    Each step the servo asks for a desired velocity (clamped to max_velocity), its
    acceleration toward it is clamped to max_acceleration, and the environment's contact force
    acts on the mass on top of it: in steady contact the slave pushes with at most
    mass * max_acceleration, and an obstacle stops it whatever its target.
    """

    def __init__(self, limits=SlaveLimits(), wall=None, box=None):
        """Set up a slave with no position yet: call reset() first."""
        self.limits = limits.checked()
        self.wall = wall
        self.box = box
        self.position = None
        self.velocity = np.zeros(3)

    def reset(self, position):
        """Put the slave at rest at `position` (m), or on the wall's surface if behind it."""
        position = _vector('position', position)
        if self.wall is not None:
            position += max(self.wall.penetration(position), 0.0) * self.wall.normal
        self.position = position
        self.velocity = np.zeros(3)

    def contact_force(self):
        """Return the environment's force (N) on the slave now."""
        force = np.zeros(3)
        if self.wall is not None:
            force += self.wall.force(self.position, self.velocity)
        if self.box is not None:
            force += self.box.force(self.position, self.velocity)
        return force

    def step(self, dt, desired_velocity):
        """Advance `dt` seconds (semi-implicit Euler) with the servo asking `desired_velocity`."""
        limits = self.limits
        wanted = clamp_norm(np.asarray(desired_velocity, dtype=float), limits.max_velocity)
        drive = clamp_norm(limits.velocity_gain * (wanted - self.velocity),
                           limits.max_acceleration)
        self.velocity = self.velocity + dt * (drive + self.contact_force() / limits.mass)
        self.position = self.position + dt * self.velocity

    def advance(self, elapsed, target=None, velocity=None):
        """
        Run `elapsed` s in steps of at most MAX_STEP; return the contact force (N) at the end.

        Give `target` (m) to servo toward a position, or `velocity` (m/s) to move at a rate.
        """
        elapsed = min(elapsed, MAX_CATCH_UP)
        steps = max(1, math.ceil(elapsed / MAX_STEP))
        dt = elapsed / steps
        for _ in range(steps):
            desired = (velocity if target is None
                       else self.limits.position_gain * (target - self.position))
            self.step(dt, desired)
        return self.contact_force()


class ArmServo:
    """
    What the arm does with its commands: follow the newest while fresh, else hold still.

    Pose mode servoes the arm toward the commanded position and takes the commanded
    orientation; twist mode moves it at the commanded velocity and turns the orientation at
    the commanded angular velocity. Until the first command the arm holds where it started;
    once the newest command is older than `timeout` s it holds where it was then. Times are
    monotonic seconds given by the caller.
    """

    def __init__(self, arm, mode, timeout):
        """Servo `arm` (a SlaveArm already reset) in `mode` ('pose' or 'twist')."""
        if mode not in MODES:
            raise ValueError(f'mode must be one of {", ".join(MODES)}, got {mode!r}')
        self.arm = arm
        self.mode = mode
        self.timeout = checked_number('command_timeout', timeout, positive=True)
        self.orientation = (0.0, 0.0, 0.0, 1.0)
        self.hold = arm.position.copy()
        self.command = None  # (position or (linear, angular), receipt time) of the newest

    def pose_command(self, position, quaternion, now):
        """Take a target pose (m; unit quaternion x, y, z, w); raise ValueError if bad."""
        position = _vector('servo_cp position', position)
        quaternion = np.array(quaternion, dtype=float)
        norm = float(np.linalg.norm(quaternion))
        if not np.all(np.isfinite(quaternion)) or abs(norm - 1.0) > QUATERNION_TOLERANCE:
            raise ValueError(f'servo_cp orientation is not a unit quaternion: '
                             f'{quaternion.tolist()}')
        self.command = (position, now)
        self.orientation = tuple((quaternion / norm).tolist())

    def twist_command(self, linear, angular, now):
        """Take a velocity (m/s) and angular velocity (rad/s); raise ValueError if bad."""
        self.command = ((_vector('servo_cv linear', linear),
                         _vector('servo_cv angular', angular)), now)

    def refuse(self):
        """Drop the command after a refused one: the arm holds where it is."""
        self.command = None

    def fresh(self, now):
        """Return whether the newest command is younger than the timeout."""
        return self.command is not None and now - self.command[1] <= self.timeout

    def advance(self, elapsed, now):
        """Run the arm `elapsed` s toward the command it has at `now`; return the contact force."""
        if self.fresh(now):
            self.hold = None
            if self.mode == 'pose':
                return self.arm.advance(elapsed, target=self.command[0])
            linear, angular = self.command[0]
            self.orientation = integrate_quaternion(self.orientation, angular, elapsed)
            return self.arm.advance(elapsed, velocity=linear)
        if self.hold is None:
            self.hold = self.arm.position.copy()
        return self.arm.advance(elapsed, target=self.hold)

    def sensor_wrench(self, contact_force):
        """Return the wrench (6) the tool applies to its wrist sensor, in the tool's frame."""
        rotation = quaternion_to_rotation(self.orientation)
        return np.concatenate([rotation.T @ np.asarray(contact_force, dtype=float),
                               np.zeros(3)])
