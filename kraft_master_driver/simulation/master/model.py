# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The simulated device's mechanics, and the workspace its operator hand keeps to.

- Six joints with inertia, viscous damping and Coulomb friction, integrated in the actuator
  coordinates q = (th1, th2, th2 + th3, th4, th5, th6) that the pots read, with the joint
  limits of Table II as rigid, inelastic end stops (the elbow's range coupled to th2).
- The operator's hand is a spring-damper per axis pulling the device toward a target; the
  motors act against it.
- Optionally the links' weight (core.gravity, the made-up SIMULATED_MASSES), taken at the pose
  of each step's start.
"""
import math
from typing import NamedTuple

from kraft_master_driver.core import kinematics
import numpy as np
from numpy.typing import ArrayLike, NDArray

JOINT_COUNT = 6
MAX_SUBSTEP = 0.5e-3  # s
OPERATOR_MARGIN = 0.1  # fraction of each joint's range the operator's targets keep clear of


class AxisDynamics(NamedTuple):
    """Model parameters per actuator axis q1..q6: the device and the operator's hand."""

    inertia: tuple  # kg*m^2
    damping: tuple  # viscous, N*m*s/rad
    friction: tuple  # Coulomb, N*m
    hand_stiffness: tuple  # N*m/rad
    hand_damping: tuple  # N*m*s/rad


# Made-up but plausible values: the paper gives no dynamics. Every axis of the hand and device
# together has a natural frequency of about 3.5 Hz, damped at about 0.8 of critical.
DEFAULT_DYNAMICS = AxisDynamics(
    inertia=(0.04, 0.04, 0.03, 0.005, 0.005, 0.002),
    damping=(0.05, 0.05, 0.04, 0.005, 0.005, 0.002),
    friction=(0.03, 0.03, 0.02, 0.005, 0.005, 0.002),
    hand_stiffness=(20.0, 20.0, 15.0, 3.0, 3.0, 1.0),
    hand_damping=(1.4, 1.4, 1.05, 0.19, 0.19, 0.07),
)
# The operator's hand off the handle.
HAND_OFF = DEFAULT_DYNAMICS._replace(hand_stiffness=(0.0,) * 6, hand_damping=(0.0,) * 6)


def joints_to_actuators(theta):
    """Return the actuator coordinates q (th3 replaced by th2 + th3) of joint angles th1..th6."""
    q = np.array(theta, dtype=float)
    q[..., 2] += q[..., 1]
    return q


def actuators_to_joints(q: ArrayLike) -> NDArray[np.float64]:
    """Return joint angles th1..th6 of actuator coordinates q (inverse of joints_to_actuators)."""
    theta = np.array(q, dtype=float)
    theta[..., 2] -= theta[..., 1]
    return theta


def elbow_upper_slope():
    """Return d(upper limit of th3)/d(th2): the elbow's range shrinks as th2 grows."""
    th2_max = kinematics.JOINT_LIMITS[1, 1]
    upper_at_max = kinematics.joint_limits(th2_max)[1][2]
    return (upper_at_max - kinematics.joint_limits(0.0)[1][2]) / th2_max


class Workspace:
    """Table II joint ranges shrunk by OPERATOR_MARGIN at each end: where the hand goes."""

    def __init__(self) -> None:
        """Compute the ranges; the elbow's upper bound is given at th2 = 0."""
        lower, upper = kinematics.joint_limits(0.0)
        margin = OPERATOR_MARGIN * (upper - lower)
        self.lower, self.upper = lower + margin, upper - margin
        self._elbow_slope = elbow_upper_slope()

    def elbow_upper(self, th2):
        """Return the upper bound of th3 at th2."""
        return self.upper[2] + self._elbow_slope * th2

    def clip(self, theta):
        """Clip joint angles (6,) in place into the workspace; return them."""
        np.clip(theta, self.lower, self.upper, out=theta)
        theta[2] = min(theta[2], self.elbow_upper(theta[1]))
        return theta

    def home(self):
        """Return the joint angles th1..th6 in the middle of the workspace."""
        home = (self.lower + self.upper) / 2.0
        home[2] = (self.lower[2] + self.elbow_upper(home[1])) / 2.0
        return home


class DeviceModel:
    """
    Six actuator axes with inertia, damping, Coulomb friction, end stops and the hand.

    The state is plain Python floats: for six axes that is several times faster than numpy.
    """

    def __init__(self, dynamics, start, weight=None):
        """
        Start at rest at joint angles `start` (6,) with the parameters `dynamics`.

        weight(theta) returns the five motor torques that hold the links up at joint angles
        theta (core.gravity); None: no gravity.
        """
        self._weight = weight
        self.q = joints_to_actuators(start).tolist()
        self.qd = [0.0] * JOINT_COUNT
        self.motor = [0.0] * JOINT_COUNT  # actuator torques, N*m; the roll stays zero
        self._inverse_inertia = [1.0 / m for m in dynamics.inertia]
        self._friction_per_inertia = [f / m for f, m in zip(dynamics.friction, dynamics.inertia)]
        self._stiffness = [float(k) for k in dynamics.hand_stiffness]
        self._damping = [b + h for b, h in zip(dynamics.damping, dynamics.hand_damping)]
        lower, upper = kinematics.joint_limits(0.0)
        self._lower, self._upper = lower.tolist(), upper.tolist()
        self._elbow_lower, self._elbow_upper = self._lower[2], self._upper[2]
        self._elbow_upper_slope = elbow_upper_slope()

    def step(self, elapsed, target):
        """Advance `elapsed` seconds, the hand pulling toward actuator coordinates `target`."""
        substeps = max(1, math.ceil(elapsed / MAX_SUBSTEP))
        dt = elapsed / substeps
        q, qd, lower, upper = self.q, self.qd, self._lower, self._upper
        motor = self.motor
        if self._weight is not None:
            holding = self._weight(self.joint_angle_list())
            motor = [torque - held for torque, held in zip(motor, [*holding, 0.0])]
        axes = [(axis, dt * inverse_inertia, dt * friction, torque + stiffness * goal,
                 stiffness, damping)
                for axis, (inverse_inertia, friction, torque, stiffness, goal, damping)
                in enumerate(zip(self._inverse_inertia, self._friction_per_inertia,
                                 motor, self._stiffness, target, self._damping))]
        for _ in range(substeps):
            for axis, velocity_per_torque, stiction, drive, stiffness, damping in axes:
                # Semi-implicit Euler; Coulomb friction as an impulse that can stop the axis.
                velocity = qd[axis] + velocity_per_torque * (
                    drive - stiffness * q[axis] - damping * qd[axis])
                if velocity > stiction:
                    velocity -= stiction
                elif velocity < -stiction:
                    velocity += stiction
                else:
                    velocity = 0.0
                position = q[axis] + dt * velocity
                # Rigid, inelastic end stops.
                if position < lower[axis]:
                    position, velocity = lower[axis], 0.0
                elif position > upper[axis]:
                    position, velocity = upper[axis], 0.0
                q[axis], qd[axis] = position, velocity
                if axis == 1:
                    # The elbow's range is in th3 = q3 - q2; its upper bound falls as th2 grows.
                    lower[2] = position + self._elbow_lower
                    upper[2] = position + self._elbow_upper + self._elbow_upper_slope * position

    def joint_angles(self):
        """Return the joint angles th1..th6 (rad)."""
        return actuators_to_joints(self.q)

    def joint_angle_list(self):
        """Return joint_angles() as a list of floats, without numpy."""
        theta = list(self.q)
        theta[2] -= theta[1]
        return theta
