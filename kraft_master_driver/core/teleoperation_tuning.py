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
ramps from the blend of that ramp: the wrench never steps.
"""
from typing import NamedTuple, Optional

from kraft_master_driver.core.teleoperation_force import ForcePath
from kraft_master_driver.core.teleoperation_settings import Array, Settings

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
