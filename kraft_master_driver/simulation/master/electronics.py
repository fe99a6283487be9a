# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The simulated device's electronics, between the link and the mechanics (model.py).

- The received torque counts / torque_scale (N*m) drive actuator axes 1..5 directly
  (coupling 'actuator') or are joint torques mapped onto the actuators (coupling 'joint');
  the wrist roll has no motor. Counts beyond torque_limit are clamped.
- A watchdog zeroes the torques when no command arrives for command_timeout, as amplifier
  electronics with a watchdog would.
- Pots read the device's true calibration (with optional Gaussian noise), within the range the
  frame carries.
"""
import math
import operator

from kraft_master_driver.core import kinematics
from kraft_master_driver.link.protocol import (
    AXIS_COUNT, INT16_MAX, STATUS_AMPLIFIERS_ENABLED, STATUS_COMMAND_CLAMPED,
    STATUS_COMMAND_TIMEOUT, STATUS_CORRUPT_COMMAND)
from kraft_master_driver.simulation.master.model import JOINT_COUNT
import numpy as np

COUPLINGS = ('actuator', 'joint')


def _axis_values(values, name, valid, requirement):
    """Return `values` as AXIS_COUNT floats that all pass `valid`, or raise ValueError."""
    try:
        array = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        array = None
    if array is None or array.shape != (AXIS_COUNT,) or not np.all(valid(array)):
        raise ValueError(f'{name} must be {AXIS_COUNT} {requirement}, got {values!r}')
    return array


class Electronics:
    """The motor amplifiers with their watchdog, the pot converters and the status byte."""

    def __init__(self, model, calibration, *, coupling, torque_scale, torque_limit,
                 command_timeout, pot_noise_counts, noise_rng, pot_range):
        """
        Drive the motors of `model` (a DeviceModel); read its pots through `calibration`.

        torque_scale is in command counts per N*m, torque_limit in counts; command_timeout
        (s) is the watchdog's; the pot noise (counts, 1 sigma) is drawn from noise_rng; pot
        counts are clipped to pot_range (lowest, highest).
        """
        scale = _axis_values(torque_scale, 'torque_scale',
                             lambda x: np.isfinite(x) & (x != 0.0), 'finite non-zero numbers')
        self._inverse_scale = tuple(1.0 / scale)
        limits = _axis_values(torque_limit, 'torque_limit', lambda x: (x >= 0) & (x <= INT16_MAX),
                              f'counts within 0..{INT16_MAX}')
        self._limits = tuple(int(x) for x in limits)
        if coupling not in COUPLINGS:
            raise ValueError(f'coupling must be one of {", ".join(COUPLINGS)}, got {coupling!r}')
        self.coupling = coupling
        if not 0.0 <= pot_noise_counts < math.inf:
            raise ValueError(f'pot_noise_counts must be >= 0, got {pot_noise_counts!r}')
        self._noise = float(pot_noise_counts)
        self._noise_rng = noise_rng
        self._pot_low, self._pot_high = pot_range
        self._command_timeout = command_timeout
        self._model = model
        self._calibration = calibration
        self._last_command = 0.0
        self._amplifiers = False
        self._timed_out = False
        self._errors_reported = 0

    def clamped(self, counts):
        """Return True if any command count is beyond its axis limit."""
        return any(not -limit <= count <= limit for count, limit in zip(counts, self._limits))

    def drive(self, counts, now):
        """Set the motor torques from command counts, each clamped to its axis limit."""
        torques = [min(max(count, -limit), limit) * inverse_scale for count, limit, inverse_scale
                   in zip(counts, self._limits, self._inverse_scale)]
        if self.coupling == 'joint':
            torques = kinematics.actuator_torques(torques).tolist()
        self._model.motor[:AXIS_COUNT] = torques
        self.restart_watchdog(now)
        self._amplifiers = True

    def restart_watchdog(self, now):
        """Count the watchdog's timeout from `now` (monotonic seconds)."""
        self._last_command = now

    def watchdog(self, now):
        """Zero the torques if no command came for command_timeout; return True if so now."""
        if not (self._amplifiers and now - self._last_command > self._command_timeout):
            return False
        self._model.motor[:] = [0.0] * JOINT_COUNT
        self._amplifiers = False
        self._timed_out = True
        return True

    def status(self, clamped, decode_errors):
        """
        Return the status byte of a reply.

        The amplifiers are on; bits for a clamped command, for a command decode error since
        the last status (decode_errors is the decoder's total) and for a watchdog timeout.
        """
        status = STATUS_AMPLIFIERS_ENABLED
        if clamped:
            status |= STATUS_COMMAND_CLAMPED
        if decode_errors != self._errors_reported:
            self._errors_reported = decode_errors
            status |= STATUS_CORRUPT_COMMAND
        if self._timed_out:
            self._timed_out = False
            status |= STATUS_COMMAND_TIMEOUT
        return status

    def read_pots(self):
        """Return the six pot counts the device reads now (true calibration, noise, range)."""
        pots = self._calibration.joints_to_frame(self._model.joint_angle_list())
        if self._noise:
            pots = map(operator.add, pots,
                       self._noise_rng.normal(0.0, self._noise, JOINT_COUNT).tolist())
        low, high = self._pot_low, self._pot_high
        return [min(max(round(count), low), high) for count in pots]
