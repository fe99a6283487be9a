# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The teleoperation bridge's force path, no ROS: the wrist F/T reading -> the master's wrench.

The reading (the wrench the tool applies to the sensor, in the sensor's frame) less the tare
bias and the tool's weight is the contact wrench. Turned into the arm's base frame, then into
the master's, it is scaled, dead-banded, low-passed and limited in length. With
slave_port_force 'sent', the moment is reflected only while the arm's orientation follows
the master's.
"""
import math
from typing import Optional

from kraft_master_driver.core.rotations import clamp_norm, cross, norm
from kraft_master_driver.core.teleoperation_settings import Array, MAX_STEP, Settings
import numpy as np


def _dead_band(vector: Array, band: float) -> Array:
    """Shrink a vector's length by `band`, to zero below it: no step at its edge."""
    length = norm(vector)
    return vector * (max(length - band, 0.0) / length) if length > 0.0 else vector


class ForcePath:
    """From F/T readings to the master's wrench: bias, tool weight, frames, filter, limits."""

    def __init__(self, settings: Settings, sensor_rotation: Array) -> None:
        """Take the settings and the sensor's rotation in the arm's measured tool frame."""
        self.settings = settings
        self.sensor_rotation = sensor_rotation
        self.bias = np.zeros(6)
        self._filtered = np.zeros(6)
        self._filtered_at: Optional[float] = None

    def retuned(self, settings: Settings, sensor_rotation: Array) -> 'ForcePath':
        """Return a path with new settings that keeps this one's bias and low-pass state."""
        path = ForcePath(settings, sensor_rotation)
        path.bias = self.bias
        path._filtered, path._filtered_at = self._filtered, self._filtered_at
        return path

    def _sensor_in_base(self, arm_rotation: Array) -> Array:
        return arm_rotation @ self.sensor_rotation

    def tool_weight(self, arm_rotation: Array) -> Array:
        """Return the wrench (6, sensor frame) the tool's weight puts on the sensor."""
        settings = self.settings
        force = settings.tool_mass * (
            self._sensor_in_base(arm_rotation).T @ np.array(settings.gravity))
        return np.concatenate([force, cross(settings.tool_com, force)])

    def tare(self, reading: Array, arm_rotation: Array) -> None:
        """Take `reading`, less the tool's weight at the arm's rotation, as the bias."""
        self.bias = reading - self.tool_weight(arm_rotation)
        self._filtered = np.zeros(6)

    def contact_wrench(self, reading: Array, arm_rotation: Array) -> Array:
        """Return the environment's wrench on the tool (6, arm base frame) in a reading."""
        wrench = reading - self.bias - self.tool_weight(arm_rotation)
        rotation = self._sensor_in_base(arm_rotation)
        return np.concatenate([rotation @ wrench[:3], rotation @ wrench[3:]])

    def zero(self) -> Array:
        """Return no wrench (6 zeros); the low-pass starts anew."""
        self._filtered, self._filtered_at = np.zeros(6), None
        return np.zeros(6)

    def within_pull(self, contact: Array, stretch: float) -> Array:
        """
        Return the contact wrench with its force no larger than the arm's impedance pulls.

        stretch: how far the arm's command is from its measured tool (m). With arm_stiffness
        set, the force is at most arm_stiffness * stretch: the arm presses no harder than its
        spring, and what the sensor reads beyond that is the tool's own impact and inertia,
        which would kick the master (0: no limit).
        """
        pull = self.settings.arm_stiffness * stretch
        force = norm(contact[:3])
        if self.settings.arm_stiffness <= 0.0 or force <= pull:
            return contact
        return np.concatenate([contact[:3] * (pull / force), contact[3:]])

    def master_wrench(self, contact: Array, base_rotation: Array, now: float) -> Array:
        """Return the master's wrench (6, master base frame) of a contact wrench at `now`."""
        settings = self.settings
        back = base_rotation.T
        force = _dead_band(settings.force_scale * (back @ contact[:3]), settings.force_deadband)
        # Booking the force sent, the master feels the arm's moment only if its rotation turns
        # the arm: otherwise the moment turns the wrist for nothing, and no port books it.
        reflects_moment = (settings.orientation == 'follow'
                           or settings.slave_port_force == 'contact')
        moment = np.zeros(3)
        if reflects_moment:
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
