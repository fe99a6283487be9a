# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
What the machine did during a benchmark run, and what it allows at all.

cpu_times() and steal_fraction(): the CPU time the hypervisor stole. bare_loop(): a loop that
does nothing but sleep to each deadline, paced like the driver's, so that the driver's cycle
rate can be read against the rate this machine gives a do-nothing loop at the same moment.
bare_pty(): the same loop exchanging a command and a reply of the device's sizes over a
pseudo-terminal with an echoing process, so that the driver's period can be read against what
the pseudo-terminal alone allows. bare_work(): the same loop doing a fixed amount of the
driver's own Python work (its kinematics) after each wake-up, so that the time the driver's
loop runs in a cycle can be read against how long the same work takes on this machine.
"""
import argparse
import json
import os
import pathlib
import subprocess
import sys
import time
import tty

import numpy as np


def cpu_times():
    """Return the machine's CPU time counters (ticks) from the first line of /proc/stat."""
    names = ('user', 'nice', 'system', 'idle', 'iowait', 'irq', 'softirq', 'steal')
    values = pathlib.Path('/proc/stat').read_text().split('\n', 1)[0].split()[1:9]
    return dict(zip(names, map(int, values)))


def steal_fraction(start, end):
    """Share of all CPU time between two cpu_times() readings that the hypervisor took."""
    total = sum(end.values()) - sum(start.values())
    return (end['steal'] - start['steal']) / total if total else 0.0


def _set_fifo(priority):
    """Run the calling process SCHED_FIFO at `priority` (0 or refused: normal); say which."""
    if priority:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            return f'SCHED_FIFO {priority}'
        except OSError:
            pass
    return 'normal'


def bare_loop(rate_hz, seconds, priority):
    """
    Run pace_nothing() in a child process; return its figures.

    priority: SCHED_FIFO priority of the child (0, or refused by the OS: normal scheduling).
    """
    output = subprocess.run(
        [sys.executable, '-m', 'benchmarks.machine', str(rate_hz), str(seconds), str(priority)],
        check=True, capture_output=True, text=True).stdout
    return json.loads(output)


class Pacer:
    """
    Deadlines `1 / rate_hz` apart for `seconds`, each slept to, with the driver's rule.

    As the driver's loop: a late cycle runs at once, and skip_to() skips the whole periods that
    cannot be caught up.
    """

    def __init__(self, rate_hz, seconds):
        """Start now."""
        self.period_ns = round(1e9 / rate_hz)
        self.start = self.deadline = time.monotonic_ns()
        self.end = self.start + round(seconds * 1e9)

    def __iter__(self):
        """Sleep to each deadline in turn; yield it."""
        while self.deadline < self.end:
            self.deadline += self.period_ns
            time.sleep(max(0, self.deadline - time.monotonic_ns()) / 1e9)
            yield self.deadline

    def skip_to(self, now):
        """Skip the whole periods that passed between the deadline and `now`; return how many."""
        skipped = max(0, (now - self.deadline) // self.period_ns)
        self.deadline += skipped * self.period_ns
        return skipped

    def elapsed_s(self):
        """Return the seconds since the start."""
        return (time.monotonic_ns() - self.start) / 1e9


def pace_nothing(rate_hz, seconds, priority):
    """
    Sleep to each deadline for `seconds`, with the driver's rule for a late wake-up (Pacer).

    Return cycles/s, missed cycles/s, how late each wake-up was (median, p99, max,
    microseconds), the scheduler used and the steal share.
    """
    scheduler = _set_fifo(priority)
    lateness = []
    missed = 0
    machine_start = cpu_times()
    pacer = Pacer(rate_hz, seconds)
    for deadline in pacer:
        now = time.monotonic_ns()
        lateness.append(now - deadline)
        missed += pacer.skip_to(now)
    elapsed = pacer.elapsed_s()
    lateness.sort()
    return {
        'rate_hz': rate_hz,
        'scheduler': scheduler,
        'cycles_per_s': len(lateness) / elapsed,
        'missed_per_s': missed / elapsed,
        'wake_late_us': {'median': lateness[len(lateness) // 2] / 1e3,
                         'p99': lateness[int(0.99 * (len(lateness) - 1))] / 1e3,
                         'max': lateness[-1] / 1e3},
        'cpu_steal': steal_fraction(machine_start, cpu_times()),
    }


def bare_pty(rate_hz, seconds, priority, device_priority, command_size, reply_size):
    """Run pace_pty_exchange() in a child process; return its figures."""
    output = subprocess.run(
        [sys.executable, '-m', 'benchmarks.machine', str(rate_hz), str(seconds), str(priority),
         '--pty',
         str(device_priority), str(command_size), str(reply_size)],
        check=True, capture_output=True, text=True).stdout
    return json.loads(output)


def bare_work(rate_hz, seconds, priority, work_us):
    """Run pace_work() in a child process; return its figures."""
    output = subprocess.run(
        [sys.executable, '-m', 'benchmarks.machine', str(rate_hz), str(seconds), str(priority),
         '--work-us', str(work_us)], check=True, capture_output=True, text=True).stdout
    return json.loads(output)


def pace_work(rate_hz, seconds, priority, work_us):
    """
    After each wake-up, run the driver's kinematics as many times as take `work_us` alone.

    The count of calls is fixed before the run from their median time at that moment. Return
    cycles/s, the calls per cycle, and the wall and CPU time of each cycle's work (median,
    p99, max, ms); the wall time also counts the time the thread waited for a CPU.
    """
    from kraft_master_driver.core.kinematics import forward_and_jacobian_entries

    scheduler = _set_fifo(priority)
    theta = [0.1, 0.2, -0.3, 0.4, -0.5, 0.6]
    times = []
    for _ in range(200):
        start = time.perf_counter_ns()
        forward_and_jacobian_entries(theta)
        times.append(time.perf_counter_ns() - start)
    calls = max(1, round(work_us * 1e3 / sorted(times)[len(times) // 2]))
    wall, cpu = [], []
    machine_start = cpu_times()
    pacer = Pacer(rate_hz, seconds)
    for _deadline in pacer:
        start, start_cpu = time.monotonic_ns(), time.thread_time_ns()
        for _ in range(calls):
            forward_and_jacobian_entries(theta)
        wall.append(time.monotonic_ns() - start)
        cpu.append(time.thread_time_ns() - start_cpu)
        pacer.skip_to(time.monotonic_ns())
    return {
        'rate_hz': rate_hz,
        'scheduler': scheduler,
        'cycles_per_s': len(wall) / pacer.elapsed_s(),
        'calls_per_cycle': calls,
        'work_wall_ms': _percentiles_ms(wall),
        'work_cpu_ms': _percentiles_ms(cpu),
        'cpu_steal': steal_fraction(machine_start, cpu_times()),
    }


def _read_exactly(fd, size):
    data = b''
    while len(data) < size:
        chunk = os.read(fd, size - len(data))
        if not chunk:
            raise EOFError
        data += chunk
    return data


def pace_pty_exchange(rate_hz, seconds, priority, device_priority, command_size, reply_size):
    """
    At each deadline, write a command and read a reply over a raw pseudo-terminal.

    A forked process at `device_priority` answers each command with a reply, as the simulated
    device does; the loop runs at `priority` with the driver's rule for a late wake-up. Return
    cycles/s, the period between replies and the round trip (median, p99, max, ms).
    """
    device, port = os.openpty()
    tty.setraw(port)
    answerer = os.fork()
    if answerer == 0:
        os.close(port)
        _set_fifo(device_priority)
        try:
            while True:
                _read_exactly(device, command_size)
                os.write(device, bytes(reply_size))
        except (EOFError, OSError):
            os._exit(0)
    os.close(device)
    scheduler = _set_fifo(priority)
    replies, round_trips = [], []
    machine_start = cpu_times()
    pacer = Pacer(rate_hz, seconds)
    for _deadline in pacer:
        sent = time.monotonic_ns()
        os.write(port, bytes(command_size))
        _read_exactly(port, reply_size)
        replies.append(time.monotonic_ns())
        round_trips.append(replies[-1] - sent)
        pacer.skip_to(replies[-1])
    elapsed = pacer.elapsed_s()
    os.close(port)
    os.waitpid(answerer, 0)
    return {
        'rate_hz': rate_hz,
        'scheduler': scheduler,
        'cycles_per_s': len(replies) / elapsed,
        'period_ms': _percentiles_ms(np.diff(replies)),
        'round_trip_ms': _percentiles_ms(round_trips),
        'cpu_steal': steal_fraction(machine_start, cpu_times()),
    }


def _percentiles_ms(values_ns):
    values = np.sort(np.asarray(values_ns)) / 1e6
    return {'median': float(values[len(values) // 2]),
            'p99': float(values[int(0.99 * (len(values) - 1))]), 'max': float(values[-1])}


def main():
    """Print pace_nothing()'s, pace_pty_exchange()'s or pace_work()'s figures as JSON."""
    parser = argparse.ArgumentParser(description=pace_nothing.__doc__.strip().splitlines()[0])
    parser.add_argument('rate_hz', type=float)
    parser.add_argument('seconds', type=float)
    parser.add_argument('priority', type=int)
    parser.add_argument('--pty', type=int, nargs=3,
                        metavar=('DEVICE_PRIORITY', 'COMMAND_SIZE', 'REPLY_SIZE'))
    parser.add_argument('--work-us', type=float)
    args = parser.parse_args()
    if args.work_us:
        print(json.dumps(pace_work(args.rate_hz, args.seconds, args.priority, args.work_us)))
    elif args.pty:
        print(json.dumps(pace_pty_exchange(args.rate_hz, args.seconds, args.priority,
                                           *args.pty)))
    else:
        print(json.dumps(pace_nothing(args.rate_hz, args.seconds, args.priority)))


if __name__ == '__main__':
    main()
