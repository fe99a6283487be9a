# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_calibrate --identify-gravity: the arm's weight from static poses.

The device holds each of a set of poses across the workspace under a PD hold through the link
(the operator's hand off the handle). The torque the hold commands is what holds the arm up,
plus what Coulomb friction takes. Each pose is reached once from above and once from below, so
that friction, which opposes the last motion, enters with both signs and the least squares
averages it out (the dVRK's MTM gravity identification approaches its poses from both
directions for the same reason). A swing of the held target (a dither) to average friction out
was tried and not kept: on a loaded machine the Python loop's late cycles made it worse. The
base parameters of core/gravity.py follow by least squares over every
hold. A handle released with them (release_drift) shows what they are worth.
"""
import math
import time
from typing import Callable, NamedTuple, Sequence

from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import CalibrationError
from kraft_master_driver.core.gravity import BASE_NAMES, GravityModel
from kraft_master_driver.tools import torque_check
from kraft_master_driver.tools.torque_check import AXES, CYCLE_PERIOD
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

# Poses (deg, th1..th5) across the workspace: the shoulder and elbow over their ranges, the
# wrist turned both ways. th1 turns about gravity's axis and changes nothing.
POSES_DEG = (
    (0, 20, -60, 0, 0), (0, 20, -110, 30, 30), (0, 50, -70, -30, 0), (20, 50, -100, 0, 40),
    (0, 80, -80, 30, -5), (-20, 80, -115, -30, 20), (0, 100, -90, 0, 0),
    (0, 100, -120, 30, 40), (0, 35, -80, -40, -5), (0, 65, -95, 40, 10),
    (10, 90, -100, -20, 30), (0, 40, -125, 20, -5),
)


SATURATED_CYCLES = 200  # a hold at its torque limit this long is refused


class Settings(NamedTuple):
    """The hold and its timing: gains per actuator axis, torques in N*m, times in s."""

    stiffness: tuple[float, ...] = (15.0, 15.0, 10.0, 1.5, 1.5)  # N*m/rad
    damping: tuple[float, ...] = (1.0, 1.0, 0.7, 0.1, 0.1)  # N*m*s/rad
    velocity_cutoff: float = 20.0  # Hz, the low-pass on the pots' difference quotient
    torque_limit: float = 2.0  # N*m on any axis (the driver's torque_limits); more: refused
    approach: float = math.radians(4.0)  # each pose is reached from this far above and below
    move: float = 0.6  # s at least to bring the target to the next point
    speed: float = math.radians(40.0)  # rad/s at most, on average, of the target's move
    settle: float = 0.6  # s held before the torques are averaged
    window: float = 0.3  # s of torques averaged
    max_error: float = math.radians(8.0)  # a hold further than this from its pose: refused


class Hold(NamedTuple):
    """One static hold: where the arm rested (joint angles th1..th6) and the torques it took."""

    theta: tuple[float, ...]
    torques: tuple[float, ...]


class Identification(NamedTuple):
    """The fit: base parameters (kg*m), rms residual per axis (N*m), the regressor's condition."""

    base: tuple[float, ...]
    residual: tuple[float, ...]
    condition: float
    holds: int


def joints_of(q: Sequence[float]) -> tuple[float, ...]:
    """Return th1..th6 (th6 taken as 0: the handle's weight is on its roll axis) of q1..q5."""
    return (q[0], q[1], q[2] - q[1], q[3], q[4], 0.0)


def actuators_of(theta_deg: Sequence[float]) -> Array:
    """Return q1..q5 (rad) of th1..th5 in degrees."""
    theta = np.radians(np.asarray(theta_deg, dtype=float))
    q = theta.copy()
    q[2] += theta[1]
    return q


class PdHold:
    """A PD hold of the actuator coordinates on an open KmcDevice, at the driver's rate."""

    def __init__(self, device, calibration, settings: Settings = Settings()):
        """Send through `device`, read the angles through `calibration` (ArmCalibration)."""
        self.link = torque_check.TorqueCheck(device, calibration)
        self.calibration = calibration
        self.settings = settings
        self.q = self.link.cycle(torque_check.ZERO_TORQUES)
        self._velocity = np.zeros(AXES)
        self._saturated = 0  # cycles in a row at the torque limit

    def run(self, duration: float, torques_at: Callable[[float, Array, Array], Sequence[float]],
            ) -> tuple[list[Array], list[Array]]:
        """
        Cycle `duration` s of cycles sending torques_at(t, q, velocity); return q and torques.

        Time counts cycles (a late one is not made up for, as in the driver's loop), so the
        hold does the same, only slower, on a loaded machine.
        """
        angles, sent = [], []
        alpha = 1.0 - math.exp(-2.0 * math.pi * self.settings.velocity_cutoff * CYCLE_PERIOD)
        start = time.monotonic()
        for cycle in range(max(1, round(duration / CYCLE_PERIOD))):
            torques = np.asarray(torques_at(cycle * CYCLE_PERIOD, self.q, self._velocity),
                                 dtype=float)
            q = self.link.cycle(tuple(torques.tolist()))
            self._velocity += alpha * ((q - self.q) / CYCLE_PERIOD - self._velocity)
            self.q = q
            angles.append(q)
            sent.append(torques)
            time.sleep(max(0.0, start + (cycle + 1) * CYCLE_PERIOD - time.monotonic()))
        return angles, sent

    def pd(self, target: Array, q: Array, velocity: Array,
           target_velocity: Array | float = 0.0) -> Array:
        """
        Return the hold's torques toward `target`, clipped at the limit.

        CalibrationError when they stay at the limit for SATURATED_CYCLES.
        """
        settings = self.settings
        torques = (np.asarray(settings.stiffness) * (target - q)
                   + np.asarray(settings.damping) * (target_velocity - velocity))
        worst = int(np.argmax(np.abs(torques)))
        if abs(torques[worst]) <= settings.torque_limit:
            self._saturated = 0
            return torques
        self._saturated += 1
        if self._saturated >= SATURATED_CYCLES:
            self.link.zero()
            raise CalibrationError(
                f'refused: holding axis {worst + 1} needed {torques[worst]:+.2f} N*m for '
                f'{SATURATED_CYCLES * CYCLE_PERIOD:g} s (limit {settings.torque_limit:g}): '
                'torques zeroed; is the hand off the handle and the path clear?')
        return np.clip(torques, -settings.torque_limit, settings.torque_limit)

    def move(self, goal: Array) -> None:
        """Bring the target smoothly from where the arm is to `goal`."""
        settings, start = self.settings, self.q.copy()
        duration = max(settings.move, float(np.abs(goal - start).max()) / settings.speed)

        def moving(t, q, velocity):
            # Smooth: no step in the target nor in its speed.
            x = min(1.0, t / duration)
            share, rate = x * x * (3.0 - 2.0 * x), 6.0 * x * (1.0 - x) / duration
            return self.pd(start + share * (goal - start), q, velocity, rate * (goal - start))
        self.run(duration, moving)

    def move_and_hold(self, goal: Array) -> Hold:
        """Move to `goal`, hold it until the arm rests, and average the torques."""
        settings = self.settings
        self.move(goal)
        angles, sent = self.run(settings.settle + settings.window,
                                lambda t, q, velocity: self.pd(goal, q, velocity))
        kept = round(settings.window / CYCLE_PERIOD)
        q = np.mean(angles[-kept:], axis=0)
        if np.abs(q - goal).max() > settings.max_error:
            self.link.zero()
            raise CalibrationError(
                f'refused: the hold rested {math.degrees(np.abs(q - goal).max()):.1f} deg from '
                'its pose: an end stop, or a hand on the handle?')
        return Hold(joints_of(q), tuple(np.mean(sent[-kept:], axis=0).tolist()))

    def holds(self, pose_deg: Sequence[float]) -> list[Hold]:
        """Hold the pose reached from above, then from below."""
        goal = actuators_of(pose_deg)
        approach = self.settings.approach
        held = []
        for side in (1.0, -1.0):
            self.move(goal + side * approach)
            held.append(self.move_and_hold(goal))
        return held


def fit(model: GravityModel, holds: Sequence[Hold]) -> Identification:
    """Return the base parameters by least squares on the holds."""
    regressor = np.vstack([model.base_regressor(hold.theta) for hold in holds])
    torques = np.concatenate([hold.torques for hold in holds])
    base = np.linalg.lstsq(regressor, torques, rcond=None)[0]
    residual = (regressor @ base - torques).reshape(len(holds), AXES)
    scaled = regressor / np.linalg.norm(regressor, axis=0)
    return Identification(tuple(base.tolist()),
                          tuple(np.sqrt(np.mean(residual ** 2, axis=0)).tolist()),
                          float(np.linalg.cond(scaled)), len(holds))


def identify(hold: PdHold, model: GravityModel, poses=POSES_DEG,
             log: Callable[[str], None] = print) -> Identification:
    """Hold every pose from both sides and fit; the torques are zeroed at the end."""
    holds = []
    try:
        for number, pose in enumerate(poses, 1):
            pair = hold.holds(pose)
            holds += pair
            log(f'pose {number}/{len(poses)} (th1..th5 {", ".join(f"{a:g}" for a in pose)} '
                'deg): holding torques ' + ', '.join(
                    f'{np.mean([h.torques[axis] for h in pair]):+.3f}' for axis in range(AXES))
                + ' N*m')
    finally:
        hold.link.zero()
    return fit(model, holds)


def describe(result: Identification) -> list[str]:
    """Return the lines that report a fit."""
    return [
        'gravity parameters (kg*m): ' + ', '.join(
            f'{name} {value:+.5f}' for name, value in zip(BASE_NAMES, result.base)),
        f'fit over {result.holds} holds: rms residual per axis (N*m) '
        + ', '.join(f'{r:.4f}' for r in result.residual)
        + f'; condition {result.condition:.1f}',
    ]


def release_drift(hold: PdHold, model: GravityModel, base: Sequence[float],
                  pose_deg: Sequence[float], duration: float = 2.0,
                  arm: str = 'right') -> float:
    """
    Hold the pose, then give only the holding torques for `duration` s; return the drift (m).

    The drift is the largest distance of the wrist from where it was released.
    """
    goal = actuators_of(pose_deg)
    hold.move_and_hold(goal)
    released_at = kinematics.forward(joints_of(hold.q), arm)[:3, 3]
    angles, _ = hold.run(duration, lambda t, q, velocity: model.holding_torques(
        joints_of(q), base))
    hold.link.zero()
    wrists = kinematics.forward(np.array([joints_of(q) for q in angles]), arm)[:, :3, 3]
    return float(np.linalg.norm(wrists - released_at, axis=1).max())
