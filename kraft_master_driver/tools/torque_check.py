# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_calibrate --check-torques: the torque sign and rough scale of each motor axis.

The operator's hand is off the handle. For each actuator axis 1..5 in turn the check sends a
torque doublet, +tau for half the pulse then -tau for the other half (the axis leaves rest and
comes back to about rest), and reads the pots every cycle. The Jacobian's convention
(core/kinematics.py: tau = J^T F, actuator torques on q = (th1, th2, th2 + th3, th4, th5))
says a positive actuator torque on axis k drives q_k positive: the sign agrees when the largest
displacement of q_k during the doublet is positive. The scale is rough: for a frictionless
axis of inertia I the doublet moves it tau * h^2 / I (h the half pulse), so tau * h^2 / peak
is an apparent inertia, larger than the true one by friction and damping. A pulse that moves
less than min_motion is repeated at twice the torque, up to the limit.

Safety: the arm must be at rest with zero torque before each axis (else a hand is on the
handle or another source drives the motors: refused), and the first motion of any axis beyond
max_motion from its rest zeroes the torques at once and stops the check (MotionStop).
"""
import math
import time
from typing import NamedTuple

from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import CalibrationError
import numpy as np

AXES = kinematics.DRIVEN_JOINTS
ZERO_TORQUES = (0.0,) * AXES
ACTUATOR_NAMES = ('q1 = th1', 'q2 = th2', 'q3 = th2 + th3', 'q4 = th4', 'q5 = th5')
MAX_MISSED_REPLIES = 50  # consecutive commands without a reply before the check gives up
REOPEN_POLL = 0.005  # s between sends while the link is down
CYCLE_PERIOD = 0.001  # s, the driver's default loop rate
TORQUE_STEPS = (0.25, 0.5, 1.0)  # fractions of the limit tried in turn until the axis moves


class Settings(NamedTuple):
    """The check's limits: torque in N*m, times in s, motions in rad."""

    torque: float = 0.3  # the largest pulse torque
    pulse: float = 0.1  # the doublet's whole duration
    settle: float = 0.3  # zero torque after each pulse
    rest: float = 0.2  # zero torque before each axis, the arm must stay still
    rest_motion: float = math.radians(1.0)  # more while at rest: refused
    min_motion: float = math.radians(0.5)  # less during a pulse: too little to tell
    max_motion: float = math.radians(10.0)  # more, on any axis: torques zeroed, stopped


class AxisResult(NamedTuple):
    """What one axis did: its pulse torque, its signed peak displacement, the verdict."""

    axis: int  # 1..5
    torque: float  # N*m of the last pulse
    peak: float  # rad, the displacement of largest magnitude, with its sign
    half_pulse: float  # s: the push as sent (half the pulse; longer after a late cycle)

    @property
    def moved(self) -> bool:
        """Whether the axis moved enough to tell its sign (set by check_axis)."""
        return not math.isnan(self.peak)

    @property
    def agrees(self) -> bool:
        """Whether a positive torque moved the axis the positive way."""
        return self.peak > 0.0

    @property
    def apparent_inertia(self) -> float:
        """Return tau * h^2 / |peak| (kg*m^2): rough, friction and damping make it larger."""
        return self.torque * self.half_pulse ** 2 / abs(self.peak)


class MotionStop(CalibrationError):
    """An axis moved beyond the bound: the torques were zeroed and the check stopped."""


class NotAtRest(CalibrationError):
    """The arm moved with zero torque commanded: a hand on the handle or another source."""


def actuator_angles(calibration, pots):
    """Return the actuator coordinates q1..q5 (rad) of one frame of pot counts."""
    theta = calibration.pots_to_joints(np.asarray(pots, dtype=float))
    q = theta[:AXES].copy()
    q[2] += theta[1]
    return q


class TorqueCheck:
    """Runs the doublets on an open KmcDevice, reading angles through a pot calibration."""

    def __init__(self, device, calibration, settings=Settings(), log=print):
        """Use `device` (open) and `calibration` (ArmCalibration); report with `log`."""
        self.device = device
        self.calibration = calibration
        self.settings = settings
        self._log = log
        self._rest = None

    def cycle(self, torques):
        """Send `torques` (N*m, axes 1..5) and return q1..q5 (rad) read back."""
        missed = 0
        while True:
            if self.device.send(torques):
                result = self.device.receive()
                if result is not None:
                    return actuator_angles(self.calibration, result.frame.pots)
            else:
                time.sleep(REOPEN_POLL)
            missed += 1
            if missed >= MAX_MISSED_REPLIES:
                raise CalibrationError(f'{self.device.port}: no reply from the device '
                                       f'({self.device.last_error or "timeouts"})')

    def zero(self):
        """Command zero torque at once (best effort: the device's close() zeroes too)."""
        try:
            self.cycle(ZERO_TORQUES)
        except CalibrationError:
            pass

    def _run(self, duration, torques_at, watch):
        """Cycle for `duration` s with torques_at(t); return the q read, (n, 5)."""
        angles = []
        start = time.monotonic()
        while True:
            elapsed = time.monotonic() - start
            if elapsed >= duration and angles:
                return np.array(angles)
            q = self.cycle(torques_at(elapsed))
            angles.append(q)
            watch(q)
            # Paced as the driver's loop: a late cycle is not made up for.
            time.sleep(max(0.0, start + len(angles) * CYCLE_PERIOD - time.monotonic()))

    def _bound(self, during):
        """Return watch(q): stop at once on a motion beyond max_motion from rest."""
        def watch(q):
            moved = np.abs(q - self._rest)
            worst = int(np.argmax(moved))
            if moved[worst] > self.settings.max_motion:
                self.zero()
                raise MotionStop(
                    f'STOPPED: axis {worst + 1} ({ACTUATOR_NAMES[worst]}) moved '
                    f'{math.degrees(moved[worst]):.1f} deg (bound '
                    f'{math.degrees(self.settings.max_motion):g} deg) {during}: torques zeroed; '
                    'lower --torque or --pulse')
        return watch

    def at_rest(self, before):
        """Read the arm at zero torque for `rest` s; NotAtRest if it moves; keep its rest."""
        angles = self._run(self.settings.rest, lambda _: ZERO_TORQUES, lambda _: None)
        spread = angles.max(axis=0) - angles.min(axis=0)
        worst = int(np.argmax(spread))
        if spread[worst] > self.settings.rest_motion:
            raise NotAtRest(
                f'refused: axis {worst + 1} ({ACTUATOR_NAMES[worst]}) moved '
                f'{math.degrees(spread[worst]):.1f} deg with zero torque commanded {before} '
                f'(limit {math.degrees(self.settings.rest_motion):g} deg): take the hand off '
                'the handle, park the arm where it stays, and stop any other program or '
                'driver that sends torques')
        self._rest = angles.mean(axis=0)

    def pulse(self, axis, torque):
        """Send one doublet of `torque` N*m on axis (1..5); return its AxisResult."""
        half = self.settings.pulse / 2.0
        push = tuple(torque if k == axis - 1 else 0.0 for k in range(AXES))
        pull = tuple(-t for t in push)
        pulled_at = []

        def doublet(elapsed):
            if elapsed < half:
                return push
            if not pulled_at:
                pulled_at.append(elapsed)
            return pull
        angles = self._run(self.settings.pulse, doublet,
                           self._bound(f'during the pulse on axis {axis}'))
        self._run(self.settings.settle, lambda _: ZERO_TORQUES,
                  self._bound(f'after the pulse on axis {axis}'))
        moved = angles[:, axis - 1] - self._rest[axis - 1]
        peak = float(moved[int(np.argmax(np.abs(moved)))])
        # The push as it was sent: a late cycle lengthens it, and the motion with it.
        return AxisResult(axis, torque, peak, pulled_at[0] if pulled_at else half)

    def check_axis(self, axis):
        """Pulse `axis` at rising torques until it moves min_motion; return its AxisResult."""
        for fraction in TORQUE_STEPS:
            self.at_rest(f'before the pulse on axis {axis}')
            result = self.pulse(axis, fraction * self.settings.torque)
            if abs(result.peak) >= self.settings.min_motion:
                return result
        return result._replace(peak=math.nan)

    def run(self, axes=range(1, AXES + 1)):
        """Check each axis in turn; return the AxisResults. Raises MotionStop, NotAtRest."""
        results = []
        try:
            for axis in axes:
                results.append(self.check_axis(axis))
                self._log(report_line(results[-1], self.settings))
        finally:
            self.zero()
        return results


def report_line(result, settings):
    """Return one line: the axis, the torque, the motion, the verdict and the rough scale."""
    where = f'axis {result.axis} ({ACTUATOR_NAMES[result.axis - 1]}):'
    if not result.moved:
        return (f'{where} moved less than {math.degrees(settings.min_motion):g} deg at '
                f'{result.torque:g} N*m: sign unknown; raise --torque if that is safe')
    verdict = 'sign agrees' if result.agrees else 'sign REVERSED'
    return (f'{where} {verdict}: {result.torque:g} N*m for {2 * result.half_pulse:g} s '
            f'moved it {math.degrees(result.peak):+.2f} deg; apparent inertia '
            f'{result.apparent_inertia:.3g} kg*m^2 (rough: friction and damping add to it)')


def measured_signs(results, applied):
    """Return the torque_signs to write: the signs applied, flipped where an axis disagreed."""
    return [int(sign) if result.agrees else -int(sign)
            for result, sign in zip(results, applied)]
