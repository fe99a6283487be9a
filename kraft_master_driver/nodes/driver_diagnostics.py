# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The diagnostics of kraft_master_node as text: level, message and key/value pairs.

A pure function of what the driver's parts report; no ROS here (the node wraps the result in a
DiagnosticStatus).
"""
from typing import NamedTuple

OK, WARN, ERROR = 'ok', 'warn', 'error'
# s without a wrench while a publisher is matched: the middleware may deliver nothing (a soak
# saw a driver take none for 27 minutes while a recorder on the same domain took them all).
SILENT_SOURCE_S = 1.0


class DriverReadings(NamedTuple):
    """What the driver's parts report at one moment, for its diagnostics."""

    statistics: object  # core.loop_statistics.LoopStatistics of the loop
    scheduler: str  # the loop thread's scheduling, as the loop reports it
    device_stats: dict  # link.device.KmcDevice.stats
    link_state: str  # None while the link is up, else what the loop waits for and why
    force: object  # core.force_reflection.ForceReflection: enabled, counters
    force_state: str  # state of the last torques sent, None before the first estimate
    wrench_sources: int  # publishers matched on wrench
    sources_refused: str  # None, or why the wrenches of several sources are refused
    calibration: str  # where the calibration came from
    port: str  # the device's port parameter
    master_port: object  # core.passivity.MasterPort: energies, observer, enabled
    slave_energy: tuple  # the slave's energy in, out, dissipated (J), as last received
    slave_link: tuple  # link_quality.LinkMonitor.summary() of slave_energy, or None
    memory_lock: str = 'not locked'  # whether the loop's memory lock was granted, and why not
    executor_scheduler: str = 'normal'  # the executor thread's scheduling, as the loop set it
    wrench_age: float | None = None  # s since the newest wrench was taken, None before the first


def milliseconds(name, median_p99_max):
    """Return the keys and texts (ms) of a (median, p99, max) in seconds."""
    return {f'{name} {label} (ms)': f'{1e3 * seconds:.3f}'
            for label, seconds in zip(('median', 'p99', 'max'), median_p99_max)}


def link_values(direction, link):
    """Return the keys and texts of a LinkMonitor.summary(): delay (ms) and loss (%)."""
    return {**milliseconds(f'{direction} delay', link[:3]),
            f'{direction} loss (%)': f'{100.0 * link[3]:.1f}'}


def driver_diagnostics(readings):
    """Return (level, message, values): OK, WARN or ERROR, one line, {key: text}."""
    statistics = readings.statistics
    force = readings.force
    values = {
        'loop rate (Hz)': f'{statistics.rate_hz():.1f}',
        **milliseconds('period', statistics.periods.percentiles_s()),
        **milliseconds('link round trip', statistics.round_trips.percentiles_s()),
        'pot frames received': str(statistics.frames),
        'pot frames published': str(statistics.published),
        'late cycles': str(statistics.late),
        'missed cycles': str(statistics.missed),
        **{f'cpu per cycle {phase} (us)': f'{1e6 * seconds:.1f}'
           for phase, seconds in statistics.cpu_per_cycle().items()},
        'internal errors': str(statistics.internal_errors),
        'loop scheduler': readings.scheduler,
        'executor scheduler': readings.executor_scheduler,
        'memory lock': readings.memory_lock,
        'force output': 'enabled' if force.enabled else 'disabled',
        'force state': readings.force_state or 'no_state',
        'wrench sources': str(readings.wrench_sources),
        'wrench age (s)': ('none yet' if readings.wrench_age is None
                           else f'{readings.wrench_age:.3f}'),
        'calibration': readings.calibration,
        'port': readings.port,
    }
    values.update({f'link {key}': str(value) for key, value in readings.device_stats.items()})
    values.update({f'force {key}': str(value) for key, value in force.counters.items()})
    level, message = OK, 'running'
    if readings.link_state is not None:
        level, message = ERROR, readings.link_state
    elif readings.sources_refused is not None:
        level, message = WARN, f'torques zero: {readings.sources_refused}'
        values['force state'] = 'several_sources'
    elif (force.enabled and readings.wrench_sources and readings.wrench_age is not None
          and readings.wrench_age > SILENT_SOURCE_S):
        # The force state says what is felt: zero (stale), or the contact model alone.
        level, message = WARN, (f'no wrench for {readings.wrench_age:.1f} s from '
                                f'{readings.wrench_sources} matched publisher(s); force state '
                                f'{readings.force_state or "no_state"}')
    values.update(_passivity_values(readings))
    return level, message, values


def _passivity_values(readings):
    """Diagnostics of the channel: passivity, energies at each port, delay and loss."""
    port = readings.master_port
    values = {'passivity': 'on' if port.enabled else 'off'}
    for side, (energy_in, energy_out, dissipated) in (
            ('master', (port.energy_in, port.energy_out, port.dissipated)),
            ('slave', readings.slave_energy)):
        values.update({f'{side} energy in (J)': f'{energy_in:.4f}',
                       f'{side} energy out (J)': f'{energy_out:.4f}',
                       f'{side} energy dissipated (J)': f'{dissipated:.4f}'})
    values['master energy observed (J)'] = f'{port.observed:.4f}'
    if readings.slave_link is not None:
        values.update(link_values('slave to master', readings.slave_link))
    return values
