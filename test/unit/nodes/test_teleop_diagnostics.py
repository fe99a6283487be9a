# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Tests of the bridge's diagnostics as text, from its core's state, without ROS."""
import math

from kraft_master_driver.core.realtime import Scheduling
from kraft_master_driver.core.teleoperation import Teleoperation
from kraft_master_driver.core.teleoperation_settings import Settings
from kraft_master_driver.nodes.driver_diagnostics import ERROR, OK
from kraft_master_driver.nodes.teleop_diagnostics import bridge_diagnostics


def test_a_disabled_bridge_is_ok_with_its_state_and_slave_port_as_text():
    bridge = Teleoperation(Settings(mode='twist'))
    bridge.port.energy_in, bridge.port.energy_out, bridge.port.dissipated = 0.5, 0.25, 0.125
    level, message, values = bridge_diagnostics(bridge, Scheduling(thread='SCHED_FIFO 50'), None)
    assert (level, message) == (OK, 'DISABLED: not enabled')
    assert values == {
        'state': 'DISABLED', 'reason': 'not enabled', 'mode': 'twist', 'clutch': 'released',
        'passivity': 'off', 'slave energy in (J)': '0.5000', 'slave energy out (J)': '0.2500',
        'slave energy dissipated (J)': '0.1250', 'drift (mm)': '0.000',
        'input scheduler': 'SCHED_FIFO 50', 'executor scheduler': 'normal',
        'memory lock': 'not locked'}
    assert all(type(value) is str for value in values.values())


def test_a_fault_is_an_error_and_the_pose_link_is_shown_once_measured():
    bridge = Teleoperation()
    bridge.ft_reading('ft_sensor', (math.nan,) * 6, 1.0)
    level, message, values = bridge_diagnostics(bridge, Scheduling(),
                                                (0.002, 0.004, 0.005, 0.125))
    assert (level, message) == (ERROR, 'FAULT: measured_cf refused: not finite')
    assert values['state'] == 'FAULT' and values['reason'] == 'measured_cf refused: not finite'
    assert values['master to slave delay median (ms)'] == '2.000'
    assert values['master to slave loss (%)'] == '12.5'
