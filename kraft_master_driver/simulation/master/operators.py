# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The simulated operator's hand: where it pulls the device, moment by moment.

It holds the device at one pose ('hold'), sweeps each joint in turn ('sweep'), wanders
smoothly inside the workspace ('random_walk'), pushes the wrist down and back ('push') or does
a task over and over: a move sideways, a hold, a touch down, a hold pressed, a lift ('task').
The device follows the hand when no torque resists, and deflects when one is applied.
"""
import math

from kraft_master_driver.core import kinematics
from kraft_master_driver.simulation.master.model import (
    JOINT_COUNT, joints_to_actuators, Workspace)
import numpy as np

OPERATORS = ('hold', 'sweep', 'random_walk', 'push', 'task')


class HoldOperator:
    """An operator hand that holds the device at one pose."""

    def __init__(self, workspace):
        """Hold the workspace's home pose."""
        self._target = joints_to_actuators(workspace.home()).tolist()

    def target(self, _t):
        """Return the actuator coordinates (6 floats) the hand pulls toward at time t (s)."""
        return self._target

    def hold_at(self, actuator_target):
        """Hold actuator coordinates (6 values, rad) from now on."""
        self._target = [float(x) for x in actuator_target]


class SweepOperator:
    """An operator hand that sweeps each joint in turn, one sine period each, inside limits."""

    def __init__(self, workspace, period):
        """Sweep about the workspace's home, `period` seconds per joint."""
        self._home = workspace.home()
        upper = workspace.upper.copy()
        upper[2] = workspace.elbow_upper(self._home[1])
        self._amplitude = np.minimum(upper - self._home, self._home - workspace.lower)
        self._period = period
        self._theta = self._home.copy()

    def target(self, t):
        """Return the actuator coordinates (6 floats) the hand pulls toward at time t (s)."""
        cycle, phase = divmod(t / self._period, 1.0)
        joint = int(cycle) % JOINT_COUNT
        theta = self._theta
        theta[:] = self._home
        theta[joint] += self._amplitude[joint] * math.sin(2.0 * math.pi * phase)
        return joints_to_actuators(theta).tolist()


class RandomWalkOperator:
    """An operator hand that moves smoothly between random waypoints inside the workspace."""

    STEP_FRACTION = 0.25  # standard deviation of one step, as a fraction of each joint's range

    def __init__(self, workspace: Workspace, period: float, rng: np.random.Generator) -> None:
        """Start at the workspace's home; segments last 0.5..1.5 `period` s; draw from `rng`."""
        self._workspace = workspace
        self._step_sigma = self.STEP_FRACTION * (workspace.upper - workspace.lower)
        self._period = period
        self._rng = rng
        self._start = workspace.home()
        self._end = self._start.copy()
        self._t_start = 0.0
        self._t_end = 0.0

    def target(self, t: float) -> list[float]:
        """Return the actuator coordinates (6 floats) the hand pulls toward at time t (s)."""
        while t >= self._t_end:
            self._start = self._end
            self._end = self._workspace.clip(
                self._start + self._rng.normal(0.0, self._step_sigma))
            self._t_start = max(self._t_end, t - self._period)
            self._t_end = self._t_start + self._period * self._rng.uniform(0.5, 1.5)
        fraction = (t - self._t_start) / (self._t_end - self._t_start)
        blend = 0.5 - 0.5 * math.cos(math.pi * fraction)
        return joints_to_actuators(self._start + blend * (self._end - self._start)).tolist()


class PushOperator:
    """
    An operator hand that pushes the wrist straight down and back, `period` s each way.

    It takes hold when the host first commands: the first stroke starts at rest from home,
    whenever the driver starts (the simulator holds t at 0 until then).
    """

    DEPTH = 0.08  # m below the home pose at the bottom of the stroke

    def __init__(self, workspace, period):
        """Push from the workspace's home to DEPTH below it (shoulder and elbow only)."""
        self._home = workspace.home()
        self._bottom = self._home.copy()
        goal = kinematics.forward(self._home)[:3, 3] - (0.0, 0.0, self.DEPTH)
        for _ in range(20):
            pose, jac = kinematics.forward_and_jacobian(self._bottom)
            self._bottom[:3] += np.linalg.lstsq(jac[:3, :3], goal - pose[:3, 3], rcond=None)[0]
        workspace.clip(self._bottom)
        self._period = period

    def target(self, t):
        """Return the actuator coordinates (6 floats) the hand pulls toward at time t (s)."""
        blend = 0.5 - 0.5 * math.cos(math.pi * t / self._period)
        return joints_to_actuators(self._home + blend * (self._bottom - self._home)).tolist()


def wrist_target(workspace, theta, offset):
    """Return joint angles that put the wrist `offset` (m, x y z) from where `theta` puts it."""
    goal = kinematics.forward(theta)[:3, 3] + offset
    moved = np.array(theta, dtype=float)
    for _ in range(20):
        pose, jac = kinematics.forward_and_jacobian(moved)
        moved[:3] += np.linalg.lstsq(jac[:3, :3], goal - pose[:3, 3], rcond=None)[0]
    return workspace.clip(moved)


class TaskOperator:
    """
    An operator hand at a task, over and over: move, hold, touch down, hold pressed, lift.

    Each round it moves the wrist to a point drawn within SIDEWAYS of home at home's height,
    holds it, pushes DEPTH straight down (through a table below: the push deflects), holds,
    lifts back and holds again; each phase lasts `period` times its share in PHASES. Like
    'push', it takes hold when the host first commands.
    """

    SIDEWAYS = 0.03  # m each way along x and y
    DEPTH = 0.08  # m below home's height at the bottom of a touch
    PHASES = (('move', 0.75), ('hold', 0.5), ('touch', 0.75), ('press', 0.75),
              ('lift', 0.75), ('hold', 0.5))

    def __init__(self, workspace, period, rng):
        """Start at home; phases last their share of `period` s; draw the points from `rng`."""
        self._workspace = workspace
        self._home = workspace.home()
        self._period = period
        self._rng = rng
        self._round_start = 0.0
        self._round = []  # (end time, start angles, end angles) of each phase of this round
        self._above = self._home.copy()
        self._new_round(0.0)

    def _new_round(self, start):
        offset = np.append(self._rng.uniform(-self.SIDEWAYS, self.SIDEWAYS, 2), 0.0)
        above = wrist_target(self._workspace, self._home, offset)
        below = wrist_target(self._workspace, above, (0.0, 0.0, -self.DEPTH))
        ends = {'move': above, 'hold': None, 'touch': below, 'press': None, 'lift': above}
        self._round_start = start
        self._round, at, angles = [], start, self._above
        for phase, share in self.PHASES:
            at += share * self._period
            end = angles if ends[phase] is None else ends[phase]
            self._round.append((at, angles, end))
            angles = end
        self._above = above

    def target(self, t):
        """Return the actuator coordinates (6 floats) the hand pulls toward at time t (s)."""
        while t >= self._round[-1][0]:
            self._new_round(self._round[-1][0])
        begin = self._round_start
        for end, start_angles, end_angles in self._round:
            if t < end:
                break
            begin = end
        fraction = (t - begin) / (end - begin)
        blend = 0.5 - 0.5 * math.cos(math.pi * min(max(fraction, 0.0), 1.0))
        return joints_to_actuators(start_angles + blend * (end_angles - start_angles)).tolist()


def make_operator(name, workspace, period, rng):
    """Return the operator hand called `name` (one of OPERATORS)."""
    if name == 'hold':
        return HoldOperator(workspace)
    if name == 'sweep':
        return SweepOperator(workspace, period)
    if name == 'push':
        return PushOperator(workspace, period)
    if name == 'task':
        return TaskOperator(workspace, period, rng)
    return RandomWalkOperator(workspace, period, rng)
