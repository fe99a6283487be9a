# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Changes of the bridge's settings while it runs, no ROS: which ask for what, and the force ramp.

A change of the mapping (REGISTERING) while the arm is driven registers anew where the arm was
last sent, as a clutch release does: the master's motion from then on is mapped the new way,
and the arm's next target is one master step away, not wherever the new mapping would put the
old offset. A change of the force path (FORCE) takes effect over RAMP_S: the master's wrench is
blended linearly from what the settings before the change make of each reading to what the
new ones make of it, so that two wrenches dt apart differ by at most dt / RAMP_S of the
difference between the two (plus what the reading itself changed). A change during a ramp
ramps from the blend of that ramp: the wrench never steps. When the bridge starts following
(an enable, a clutch release, a pose fresh again), the wrench comes in from zero over
force_resume_time, a late tick taking at most a tenth of it, as the driver's force_ramp_time
does.
"""
from typing import NamedTuple, Optional

from kraft_master_driver.core.teleoperation_force import ForcePath
from kraft_master_driver.core.teleoperation_settings import Array, Settings
import numpy as np

RAMP_S = 0.5  # s over which a change of a force setting takes effect
REGISTERING = frozenset({'scale', 'orientation', 'base_rotation', 'passivity'})
FORCE = frozenset({'orientation', 'slave_port_force', 'base_rotation', 'sensor_rotation',
                   'force_feedback', 'tool_mass', 'tool_com', 'gravity', 'force_scale',
                   'moment_scale', 'force_deadband', 'moment_deadband', 'force_cutoff_hz',
                   'max_force', 'max_moment', 'arm_stiffness'})


def changed(before: Settings, after: Settings) -> frozenset[str]:
    """Return the names of the settings that differ between `before` and `after`."""
    return frozenset(name for name in Settings._fields
                     if getattr(before, name) != getattr(after, name))


class WrenchRamp(NamedTuple):
    """The force path as it was before a change, and when the change came (monotonic s)."""

    force: ForcePath
    force_feedback: bool
    base_rotation: Array
    start: float
    before: Optional['WrenchRamp']  # the ramp that was under way at the change

    def weight(self, now: float) -> float:
        """Return the new settings' share of the wrench at `now`: 0 at the change, 1 after."""
        return min(max((now - self.start) / RAMP_S, 0.0), 1.0)


class Sensed(NamedTuple):
    """What the master's wrench is made of while following: a reading and the arm's state."""

    reading: Array  # the F/T reading (6, sensor frame)
    arm_rotation: Array  # the arm's measured tool rotation (3x3, arm base frame)
    stretch: float  # m between the arm's command and its measured tool


class RampedForce:
    """The bridge's force path and the ramps of its changes: a master's wrench without steps."""

    def __init__(self, settings: Settings, sensor_rotation: Array) -> None:
        """Take the settings and the sensor's rotation in the arm's measured tool frame."""
        self.path = ForcePath(settings, sensor_rotation)
        self.ramp: Optional[WrenchRamp] = None  # the force path before a change, while ramping
        self.sent_force = np.zeros(3)  # N, master base frame: the last wrench's force
        # The share of the wrench given since following started (0..1), and when last given.
        self._resumed = 0.0
        self._resumed_at: Optional[float] = None

    def retune(self, before: Settings, base_rotation: Array, settings: Settings,
               sensor_rotation: Array, now: float) -> None:
        """Take new settings at `now`, ramped from `before` (and its base_rotation)."""
        self.ramp = WrenchRamp(self.path, before.force_feedback, base_rotation, now, self.ramp)
        self.path = self.path.retuned(settings, sensor_rotation)

    def tare(self, reading: Array, arm_rotation: Array) -> None:
        """Take the reading, less the tool's weight, as the bias: the wrench steps, no ramp."""
        self.path.tare(reading, arm_rotation)
        self.ramp = None

    def wrench(self, sensed: Optional[Sensed], force_feedback: bool, base_rotation: Array,
               now: float) -> Array:
        """Return the master's force and moment (6, master base frame); zeros without `sensed`."""
        if self.ramp is not None and self.ramp.weight(now) == 1.0:
            self.ramp = None
        wrench = _ramped(self.path, force_feedback, base_rotation, self.ramp, sensed, now)
        wrench = wrench * self._resume(sensed is not None, now)
        self.sent_force = wrench[:3]
        return wrench

    def _resume(self, following: bool, now: float) -> float:
        """Return the wrench's share at `now`: zero until following, then up to 1."""
        if not following:
            self._resumed, self._resumed_at = 0.0, None
            return 0.0
        resume = self.path.settings.force_resume_time
        if resume <= 0.0:
            self._resumed = 1.0
        elif self._resumed_at is not None:
            elapsed = min(max(now - self._resumed_at, 0.0), 0.1 * resume)
            self._resumed = min(1.0, self._resumed + elapsed / resume)
        self._resumed_at = now
        return self._resumed

    def port_force(self, settings: Settings, base_rotation: Array,
                   contact: Optional[Array]) -> Array:
        """
        Return the force (3, arm base frame) the slave port books; zeros if none.

        slave_port_force 'contact': the F/T contact force (`contact`, the contact wrench, None
        without a reading). 'sent': the force of the last wrench sent to the master, in the
        arm's frame and divided by scale, so that against the arm's commanded motion it is the
        power the master's port books against the master's motion: both ends count one energy
        whatever the scales, the dead band, the low-pass and the limits (a force that lags the
        command, as an arm's does, is booked as it is felt).
        """
        if settings.slave_port_force == 'sent':
            return base_rotation @ self.sent_force / settings.scale
        if not settings.force_feedback or contact is None:
            return np.zeros(3)
        return contact[:3]


def _ramped(path: ForcePath, force_feedback: bool, base_rotation: Array,
            ramp: Optional[WrenchRamp], sensed: Optional[Sensed], now: float) -> Array:
    """Return the wrench of a force path, blended from the one before while `ramp` runs."""
    if force_feedback and sensed is not None:
        contact = path.contact_wrench(sensed.reading, sensed.arm_rotation)
        wrench = path.master_wrench(path.within_pull(contact, sensed.stretch), base_rotation,
                                    now)
    else:
        wrench = path.zero()
    if ramp is None or ramp.weight(now) == 1.0:
        return wrench
    before = _ramped(ramp.force, ramp.force_feedback, ramp.base_rotation, ramp.before, sensed,
                     now)
    return before + ramp.weight(now) * (wrench - before)
