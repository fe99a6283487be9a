# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The diagnostics of kraft_master_teleop as text: level, message and key/value pairs.

A pure function of what the bridge's parts report; no ROS here (the node wraps the result in a
DiagnosticStatus), as nodes/driver_diagnostics.py is for the driver.
"""
import math

from kraft_master_driver.core.teleoperation import OperatingState
from kraft_master_driver.nodes.driver_diagnostics import ERROR, link_values, OK


def bridge_diagnostics(bridge, scheduling, pose_link):
    """
    Return (level, message, values): ERROR in FAULT else OK, the state's line, {key: text}.

    bridge: the core.teleoperation.Teleoperation; scheduling: the node's realtime.Scheduling;
    pose_link: link_quality.LinkMonitor.summary() of the master's pose, or None.
    """
    port = bridge.port
    values = {'state': str(bridge.state), 'reason': bridge.reason, 'mode': bridge.settings.mode,
              'clutch': 'pressed' if bridge.clutch_pressed else 'released',
              'passivity': 'on' if port.enabled else 'off',
              'slave energy in (J)': f'{port.energy_in:.4f}',
              'slave energy out (J)': f'{port.energy_out:.4f}',
              'slave energy dissipated (J)': f'{port.dissipated:.4f}',
              'drift (mm)': f'{1e3 * math.hypot(*port.drift):.3f}',
              'input scheduler': scheduling.thread,
              'executor scheduler': scheduling.executor,
              'memory lock': scheduling.memory_lock}
    if pose_link is not None:
        values.update(link_values('master to slave', pose_link))
    level = ERROR if bridge.state is OperatingState.FAULT else OK
    return level, bridge.describe(), values
