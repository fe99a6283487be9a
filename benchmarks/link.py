# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Time KmcDevice cycles against the simulated hand controller in another process, over a pty.

Two runs, the simulator started each time as
`python -m kraft_master_driver.simulation.master.simulator`:
- flat out, no wire timing (the software floor of pyserial over a pseudo-terminal): cycles/s
  and the round-trip time distribution (median, p99, max);
- with the simulator delaying each reply by its wire time at 115200 baud: the achieved rate as
  a fraction of the wire-limited rate (15 + 18 bytes at 10 bits per byte per cycle).
Both again with a bare far end in place of the simulator: a pty whose other end answers every
15 bytes with 18 and does nothing else, and a host that only writes and reads (os.write, poll,
os.read): what this machine's pseudo-terminals and scheduler allow any driver and device.
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
import select
import subprocess
import sys
import time
import tty

from benchmarks.machine import cpu_times, steal_fraction
from kraft_master_driver.link.device import KmcDevice
from kraft_master_driver.link.protocol import get_codec
import numpy as np

RATE_TARGET = 2000.0  # cycles/s flat out
P99_TARGET_US = 1000.0
WIRE_FRACTION_TARGET = 0.95
WIRE_BAUD = 115200
FLAT_OUT_BAUD = 1_000_000  # the device default; a pty ignores it
START_TIMEOUT_S = 30.0
CODEC = get_codec('kraft-default')
WAKE_EARLY_S = 0.0003  # as the simulator: sleep until this long before a reply is due, then spin
BARE_REPLY_TIMEOUT_MS = 50


class SimulatorProcess:
    """The simulator CLI in a child process; the context value is its port path."""

    def __init__(self, baud=None, priority=0, bare=False):
        """
        Run with wire timing at baud (None: none), serving at SCHED_FIFO priority.

        bare: run this file's bare far end (run_bare_far_end) in place of the simulator.
        """
        if bare:
            self._arguments = [sys.executable, '-m', 'benchmarks.link', '--bare-far-end', '--baud',
                               str(baud or 0), '--sim-priority', str(priority)]
        else:
            self._arguments = [sys.executable, '-m',
                               'kraft_master_driver.simulation.master.simulator',
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
        stats = device.stats
    figures = cycle_figures(cycles, round_trips[:completed], elapsed, cpu, baud, steal)
    figures.update(timeouts=stats['timeouts'], stale_replies=stats['stale_replies'])
    return figures


def cycle_figures(cycles, round_trips, elapsed, cpu, baud, steal):
    """Return the figures of a run of `cycles`: round_trips (s, one per reply), elapsed, CPU s."""
    round_trips_us = round_trips * 1e6
    return {
        'cycles': cycles,
        'replies': round_trips.size,
        'timeouts': cycles - round_trips.size,
        'rate_hz': cycles / elapsed,
        'driver_cpu_us_per_cycle': cpu / cycles * 1e6,
        'round_trip_median_us': float(np.median(round_trips_us)),
        'round_trip_p99_us': float(np.percentile(round_trips_us, 99)),
        'round_trip_max_us': float(round_trips_us.max()),
        'wire_limited_rate_hz': 1.0 / CODEC.wire_cycle_time(baud),
        'baud': baud,
        'cpu_steal': steal,
    }


def run_bare_far_end(baud, priority):
    """
    Answer every command-sized request on a new pty with a reply-sized block of zeros.

    baud: 0, or reply the wire time of a command and its reply after the request arrived, as
    the simulator's wire timing does. Prints the port path, then serves until SIGTERM.
    """
    if priority:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    master, slave = os.openpty()
    tty.setraw(slave)
    print(f'port: {os.ttyname(slave)}', flush=True)
    delay = CODEC.wire_cycle_time(baud) if baud else 0.0
    reply = bytes(CODEC.reply_size)
    pending = 0
    while True:
        pending += len(os.read(master, 4096))
        arrived = time.monotonic()
        while pending >= CODEC.command_size:
            pending -= CODEC.command_size
            if delay:
                due = arrived + delay
                time.sleep(max(0.0, due - WAKE_EARLY_S - time.monotonic()))
                while time.monotonic() < due:
                    pass
            os.write(master, reply)


def run_bare_cycles(port, cycles, warmup, baud):
    """Cycle with the bare far end: write a command's bytes, read a reply's; the figures."""
    fd = os.open(port, os.O_RDWR | os.O_NOCTTY)
    poller = select.poll()
    poller.register(fd, select.POLLIN)
    request = bytes(CODEC.command_size)
    round_trips = np.empty(cycles)
    try:
        for index in range(-warmup, cycles):
            if index == 0:
                machine_start = cpu_times()
                start = time.perf_counter()
                cpu_start = time.process_time()
            sent = time.perf_counter()
            os.write(fd, request)
            received = 0
            while received < CODEC.reply_size:
                if not poller.poll(BARE_REPLY_TIMEOUT_MS):
                    raise RuntimeError(f'{port}: no reply from the bare far end')
                received += len(os.read(fd, CODEC.reply_size - received))
            if index >= 0:
                round_trips[index] = time.perf_counter() - sent
        elapsed = time.perf_counter() - start
        cpu = time.process_time() - cpu_start
        steal = steal_fraction(machine_start, cpu_times())
    finally:
        os.close(fd)
    return cycle_figures(cycles, round_trips, elapsed, cpu, baud, steal)


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
    parser.add_argument('--bare-far-end', action='store_true', help=argparse.SUPPRESS)
    parser.add_argument('--baud', type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.bare_far_end:
        return run_bare_far_end(args.baud, args.sim_priority)
    if args.host_priority:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.host_priority))

    with SimulatorProcess(priority=args.sim_priority) as port:
        flat = run_cycles(port, args.cycles, args.cycles // 10, FLAT_OUT_BAUD)
    with SimulatorProcess(WIRE_BAUD, args.sim_priority) as port:
        wire = run_cycles(port, args.wire_cycles, 100, WIRE_BAUD)
    with SimulatorProcess(priority=args.sim_priority, bare=True) as port:
        bare_flat = run_bare_cycles(port, args.cycles, args.cycles // 10, FLAT_OUT_BAUD)
    with SimulatorProcess(WIRE_BAUD, args.sim_priority, bare=True) as port:
        bare_wire = run_bare_cycles(port, args.wire_cycles, 100, WIRE_BAUD)
    for figures in (wire, bare_wire):
        figures['fraction_of_wire_limited'] = figures['rate_hz'] / figures['wire_limited_rate_hz']

    print(f'KmcDevice <-> simulator (separate process) over a pty, then a bare host <-> a bare '
          f'far end; Python {platform.python_version()}, {os.cpu_count()} CPUs')
    header = ('run', 'cycles', 'timeouts', 'cycles/s', 'median us', 'p99 us', 'max us',
              'cpu us', 'wire-limited/s', 'achieved/wire', 'steal')
    print('{:<27}{:>8}{:>10}{:>10}{:>11}{:>9}{:>9}{:>8}{:>16}{:>15}{:>7}'.format(*header))
    rows = (('pty flat out', flat), (f'pty wire {WIRE_BAUD} baud', wire),
            ('bare pty flat out', bare_flat), (f'bare pty wire {WIRE_BAUD} baud', bare_wire))
    for name, figures in rows:
        timed = 'fraction_of_wire_limited' in figures
        limit = f'{figures["wire_limited_rate_hz"]:.0f}' if timed else '-'
        fraction = f'{figures["fraction_of_wire_limited"]:.1%}' if timed else '-'
        print(f'{name:<27}{figures["cycles"]:>8}{figures["timeouts"]:>10}'
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
          f' ({"met" if checks["wire_fraction"] else "MISSED"}; bare host and far end: '
          f'{bare_wire["fraction_of_wire_limited"]:.1%})')
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump({'flat_out': flat, 'wire_115200': wire, 'bare_flat_out': bare_flat,
                       'bare_wire_115200': bare_wire, 'targets_met': checks}, stream, indent=2)
    return 0


if __name__ == '__main__':
    sys.exit(main())
