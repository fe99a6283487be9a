# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Tests of the driver's diagnostics as text, from its parts' figures, without ROS."""
import subprocess
import sys

from kraft_master_driver.core.force_reflection import ForceReflection
from kraft_master_driver.core.loop_statistics import LoopStatistics
from kraft_master_driver.core.passivity import MasterPort
from kraft_master_driver.nodes.driver_diagnostics import (
    driver_diagnostics, DriverReadings, ERROR, OK, WARN)
import pytest


def statistics():
    """Return loop statistics of four cycles 1, 1, 2 ms apart and some counters."""
    result = LoopStatistics()
    for start_ns in (0, 1_000_000, 2_000_000, 4_000_000):
        result.record_start(start_ns)
        result.round_trips.add(200_000)
    result.add_cpu(link=120_000, kinematics=60_000, publish=30_000)
    result.frames, result.published, result.late, result.missed = 4, 2, 1, 1
    result.internal_errors = 0
    return result


def readings(**changes):
    """Return the readings of a running driver with one wrench source, changed by `changes`."""
    port = MasterPort()
    port.enabled = False
    port.energy_in, port.energy_out, port.dissipated, port.remote_in = 0.5, 0.25, 0.125, 1.0
    return DriverReadings(
        statistics=statistics(), scheduler='SCHED_FIFO 50',
        device_stats={'cycles': 5, 'timeouts': 1}, link_state=None,
        force=ForceReflection(enabled=True), force_state='active', wrench_sources=1,
        sources_refused=None, calibration='parameters', port='sim', master_port=port,
        slave_energy=(0.25, 0.0, 0.0625), slave_link=None)._replace(**changes)


def test_a_running_driver_is_ok_with_its_figures_as_text():
    level, message, values = driver_diagnostics(readings())
    assert (level, message) == (OK, 'running')
    assert values['loop rate (Hz)'] == '750.0'  # 3 periods in 4 ms
    assert values['period median (ms)'] == '1.000'
    assert values['period max (ms)'] == '2.000'
    assert values['link round trip p99 (ms)'] == '0.200'
    assert values['pot frames received'] == '4' and values['pot frames published'] == '2'
    assert values['late cycles'] == '1' and values['missed cycles'] == '1'
    assert values['cpu per cycle link (us)'] == '40.0'  # over the 3 cycles
    assert values['cpu per cycle publish (us)'] == '10.0'
    assert values['internal errors'] == '0'
    assert values['loop scheduler'] == 'SCHED_FIFO 50'
    assert values['executor scheduler'] == 'normal'
    assert values['force output'] == 'enabled' and values['force state'] == 'active'
    assert values['wrench sources'] == '1'
    assert values['calibration'] == 'parameters' and values['port'] == 'sim'
    assert values['link cycles'] == '5' and values['link timeouts'] == '1'
    assert values['force watchdog_trips'] == '0' and values['force rejected_malformed'] == '0'
    assert all(isinstance(value, str) for value in values.values())
    values = driver_diagnostics(readings(executor_scheduler='SCHED_FIFO 49'))[2]
    assert values['executor scheduler'] == 'SCHED_FIFO 49'


def test_the_channel_energies_and_passivity():
    _, _, values = driver_diagnostics(readings())
    assert values['passivity'] == 'off'
    assert values['master energy in (J)'] == '0.5000'
    assert values['master energy out (J)'] == '0.2500'
    assert values['master energy dissipated (J)'] == '0.1250'
    assert values['master energy observed (J)'] == '0.7500'  # credit 1.0 minus 0.25 out
    assert values['slave energy in (J)'] == '0.2500'
    assert values['slave energy dissipated (J)'] == '0.0625'
    assert not any(key.startswith('slave to master') for key in values)


def test_the_slave_link_delay_and_loss_once_measured():
    _, _, values = driver_diagnostics(readings(slave_link=(0.002, 0.004, 0.005, 0.125)))
    assert values['slave to master delay median (ms)'] == '2.000'
    assert values['slave to master delay p99 (ms)'] == '4.000'
    assert values['slave to master delay max (ms)'] == '5.000'
    assert values['slave to master loss (%)'] == '12.5'


def test_a_down_link_is_an_error_saying_what_the_driver_waits_for():
    level, message, values = driver_diagnostics(readings(
        link_state='waiting for the device: cannot open: No such file or directory',
        force_state=None, sources_refused='2 publishers on /wrench'))
    assert level == ERROR
    assert message == 'waiting for the device: cannot open: No such file or directory'
    assert values['force state'] == 'no_state'


def test_refused_wrench_sources_warn_and_say_why():
    level, message, values = driver_diagnostics(readings(
        wrench_sources=2, sources_refused='2 publishers on /wrench, only one is allowed'))
    assert level == WARN
    assert message == 'torques zero: 2 publishers on /wrench, only one is allowed'
    assert values['force state'] == 'several_sources'
    assert values['wrench sources'] == '2'


def test_disabled_force_and_an_empty_loop():
    level, _, values = driver_diagnostics(readings(
        statistics=LoopStatistics(), force=ForceReflection(), scheduler='normal'))
    assert level == OK
    assert values['force output'] == 'disabled'
    assert values['loop rate (Hz)'] == '0.0'
    assert values['period median (ms)'] == '0.000'
    assert values['cpu per cycle kinematics (us)'] == '0.0'


def test_the_readings_are_only_read():
    given = readings()
    before = (given.statistics.frames, given.master_port.energy_out, dict(given.device_stats))
    driver_diagnostics(given)
    driver_diagnostics(given)
    assert (given.statistics.frames, given.master_port.energy_out,
            dict(given.device_stats)) == before


@pytest.mark.process
def test_the_diagnostics_import_no_rclpy():
    code = ('import sys, kraft_master_driver.nodes.driver_diagnostics; '
            'sys.exit("rclpy" in sys.modules)')
    assert subprocess.run([sys.executable, '-c', code], timeout=60).returncode == 0


def test_a_matched_wrench_publisher_that_sends_nothing_warns():
    # A soak's driver took no wrench for 27 minutes, its diagnostics OK, while a recorder on
    # the same domain took the same publisher's wrenches.
    level, message, values = driver_diagnostics(readings(wrench_age=0.5, force_state='stale'))
    assert (level, message, values['wrench age (s)']) == (OK, 'running', '0.500')
    level, message, values = driver_diagnostics(readings(wrench_age=27.25, force_state='stale'))
    assert level == WARN
    assert message == 'no wrench for 27.2 s from 1 matched publisher(s); force state stale'
    assert values['wrench age (s)'] == '27.250'
    # None matched, none yet, or force off: nothing to wait for.
    assert driver_diagnostics(readings(wrench_age=27.25, wrench_sources=0))[0] == OK
    assert driver_diagnostics(readings())[2]['wrench age (s)'] == 'none yet'
    assert driver_diagnostics(readings(wrench_age=27.25, force=ForceReflection()))[0] == OK
