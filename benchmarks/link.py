# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Time KmcDevice cycles against the simulated hand controller in another process, over a pty.

Two runs, the simulator started each time as `python -m kraft_master_driver.simulator`:
- flat out, no wire timing (the software floor of pyserial over a pseudo-terminal): cycles/s
  and the round-trip time distribution (median, p99, max);
- with the simulator delaying each reply by its wire time at 115200 baud: the achieved rate as
  a fraction of the wire-limited rate (15 + 18 bytes at 10 bits per byte per cycle).
Targets: >= 2000 cycles/s and p99 round trip < 1 ms flat out; >= 95 % of the wire-limited
rate at 115200 baud. Prints a table (cpu us: the driver process's CPU time per cycle; steal:
the share of the machine's CPU time the hypervisor took during the run);
--json PATH also writes the figures.
"""
import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from kraft_master_driver.device import KmcDevice  # noqa: E402, I100
from machine import cpu_times, steal_fraction  # noqa: E402, I100

RATE_TARGET = 2000.0  # cycles/s flat out
P99_TARGET_US = 1000.0
WIRE_FRACTION_TARGET = 0.95
WIRE_BAUD = 115200
FLAT_OUT_BAUD = 1_000_000  # the device default; a pty ignores it
START_TIMEOUT_S = 30.0


class SimulatorProcess:
    """The simulator CLI in a child process; the context value is its port path."""

    def __init__(self, baud=None, priority=0):
        """Run with wire timing at baud (None: none), serving at SCHED_FIFO priority."""
        self._arguments = [sys.executable, '-m', 'kraft_master_driver.simulator',
                           '--priority', str(priority)]
        if baud is not None:
            self._arguments += ['--baud', str(baud)]
        self._process = None

    def __enter__(self):
        """Start the simulator and return the port path it prints."""
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        environment = dict(os.environ, PYTHONPATH=os.pathsep.join(
            filter(None, (root, os.environ.get('PYTHONPATH')))))
        self._process = subprocess.Popen(self._arguments, stdout=subprocess.PIPE, text=True,
                                         env=environment)
        deadline = time.monotonic() + START_TIMEOUT_S
        for line in self._process.stdout:
            if line.startswith('port: '):
                return line.split(' ', 1)[1].strip()
            if time.monotonic() > deadline:
                break
        self.__exit__()
        raise RuntimeError('the simulator did not print its port')

    def __exit__(self, *_exc_info):
        """Stop the simulator (SIGTERM) and wait for it."""
        self._process.terminate()
        try:
            self._process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()


def run_cycles(port, cycles, warmup, baud):
    """Run cycles back to back; return the figures of the run."""
    round_trips = np.empty(cycles)
    completed = 0
    with KmcDevice(port, baudrate=baud, reply_timeout=0.05) as device:
        if not device.link_up:
            raise RuntimeError(f'cannot open {port}: {device.last_error}')
        for index in range(warmup):
            device.cycle(torque_pattern(index))
        machine_start = cpu_times()
        start = time.perf_counter()
        cpu_start = time.process_time()
        for index in range(cycles):
            result = device.cycle(torque_pattern(index))
            if result is not None:
                round_trips[completed] = result.round_trip_s
                completed += 1
        elapsed = time.perf_counter() - start
        cpu = time.process_time() - cpu_start
        steal = steal_fraction(machine_start, cpu_times())
        wire_limited = device.wire_limited_rate()
        stats = device.stats
    round_trips_us = round_trips[:completed] * 1e6
    return {
        'cycles': cycles,
        'replies': completed,
        'timeouts': stats['timeouts'],
        'stale_replies': stats['stale_replies'],
        'rate_hz': cycles / elapsed,
        'driver_cpu_us_per_cycle': cpu / cycles * 1e6,
        'round_trip_median_us': float(np.median(round_trips_us)),
        'round_trip_p99_us': float(np.percentile(round_trips_us, 99)),
        'round_trip_max_us': float(round_trips_us.max()),
        'wire_limited_rate_hz': wire_limited,
        'baud': baud,
        'cpu_steal': steal,
    }


def torque_pattern(index):
    """Return five small torques (N*m) that change every cycle."""
    phase = index * 0.01
    return tuple(0.2 * math.sin(phase + axis) for axis in range(5))


def main():
    """Run both benchmarks, print the table, optionally write JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--cycles', type=int, default=20000, help='flat-out cycles (20000)')
    parser.add_argument('--wire-cycles', type=int, default=1500,
                        help='cycles of the 115200 baud run (1500)')
    parser.add_argument('--host-priority', type=int, default=50,
                        help='SCHED_FIFO priority of the cycling thread, as the driver '
                             "node's loop_priority (default 50; 0: normal)")
    parser.add_argument('--sim-priority', type=int, default=0,
                        help="the simulator's --priority (default 0: normal)")
    parser.add_argument('--json', metavar='PATH', help='also write the figures to PATH')
    args = parser.parse_args()
    if args.host_priority:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.host_priority))

    with SimulatorProcess(priority=args.sim_priority) as port:
        flat = run_cycles(port, args.cycles, args.cycles // 10, FLAT_OUT_BAUD)
    with SimulatorProcess(WIRE_BAUD, args.sim_priority) as port:
        wire = run_cycles(port, args.wire_cycles, 100, WIRE_BAUD)
    wire['fraction_of_wire_limited'] = wire['rate_hz'] / wire['wire_limited_rate_hz']

    print(f'KmcDevice <-> simulator (separate process) over a pty; Python '
          f'{platform.python_version()}, {os.cpu_count()} CPUs')
    header = ('run', 'cycles', 'timeouts', 'cycles/s', 'median us', 'p99 us', 'max us',
              'cpu us', 'wire-limited/s', 'achieved/wire', 'steal')
    print('{:<22}{:>8}{:>10}{:>10}{:>11}{:>9}{:>9}{:>8}{:>16}{:>15}{:>7}'.format(*header))
    for name, figures, fraction in (('pty flat out', flat, '-'),
                                    (f'pty wire {WIRE_BAUD} baud', wire,
                                     f'{wire["fraction_of_wire_limited"]:.1%}')):
        limit = (f'{figures["wire_limited_rate_hz"]:.0f}' if figures is wire else '-')
        print(f'{name:<22}{figures["cycles"]:>8}{figures["timeouts"]:>10}'
              f'{figures["rate_hz"]:>10.0f}{figures["round_trip_median_us"]:>11.0f}'
              f'{figures["round_trip_p99_us"]:>9.0f}{figures["round_trip_max_us"]:>9.0f}'
              f'{figures["driver_cpu_us_per_cycle"]:>8.0f}{limit:>16}{fraction:>15}'
              f'{figures["cpu_steal"]:>7.0%}')
    checks = {
        'flat_out_rate': flat['rate_hz'] >= RATE_TARGET,
        'flat_out_p99': flat['round_trip_p99_us'] < P99_TARGET_US,
        'wire_fraction': wire['fraction_of_wire_limited'] >= WIRE_FRACTION_TARGET,
    }
    print(f'targets: >= {RATE_TARGET:.0f} cycles/s: {flat["rate_hz"]:.0f}'
          f' ({"met" if checks["flat_out_rate"] else "MISSED"}); p99 < {P99_TARGET_US:.0f} us:'
          f' {flat["round_trip_p99_us"]:.0f} ({"met" if checks["flat_out_p99"] else "MISSED"});'
          f' >= {WIRE_FRACTION_TARGET:.0%} of wire-limited: '
          f'{wire["fraction_of_wire_limited"]:.1%}'
          f' ({"met" if checks["wire_fraction"] else "MISSED"})')
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump({'flat_out': flat, 'wire_115200': wire, 'targets_met': checks}, stream,
                      indent=2)


if __name__ == '__main__':
    main()
