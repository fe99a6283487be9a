# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Where the driver's loop thread spent the device's slow cycles, from the kernel's scheduler.

`loop.py --sched-trace` has perf record every CPU's sched_switch and sched_waking events during
a run (root, or kernel.perf_event_paranoid at -1; Debian's perf is in linux-perf). Each gap
between two commands the device received is then split by what the loop thread (kraft_loop)
did in it:

- running on a CPU;
- ready, waiting for a CPU (and what ran there instead);
- asleep, by what woke it: the simulator, a kernel worker (a pseudo-terminal's bytes reach
  their reader through one), another thread of the driver (the interpreter lock, a DDS lock),
  or anything else (its timer, which wakes it from whatever the CPU was running).

The figures are the mean time per gap in each state, over the gaps longer than SLOW_GAP_MS and
over all gaps, and for each slow gap the state that had the most time beyond its mean. Beside
them, how long the kernel workers woken in a gap waited for a CPU.
"""
import bisect
import collections
import re
import shutil
import signal
import subprocess

import numpy as np

SLOW_GAP_MS = 1.25
LOOP_THREAD = 'kraft_loop'  # nodes.driver.LOOP_THREAD
RUNNING, WAITING = 'running', 'waiting for a CPU'
WOKEN_BY = ('simulator', 'kernel worker', 'driver thread', 'timer or other')
STATES = (RUNNING, WAITING, *(f'asleep, woken by {waker}' for waker in WOKEN_BY))
_SAMPLE = re.compile(r'^\s*(?P<comm>.*?)\s+(?P<pid>-?\d+)/(?P<tid>\d+)\s+\[(?P<cpu>\d+)\]\s+'
                     r'(?P<time>\d+)\.(?P<ns>\d{9}):\s+sched:(?P<event>\w+):\s+(?P<trace>.*)$')
_SWITCH = re.compile(r'prev_comm=.* prev_pid=(?P<prev>\d+) prev_prio=-?\d+ '
                     r'prev_state=(?P<state>\S+) ==> next_comm=(?P<next_comm>.*) '
                     r'next_pid=(?P<next>\d+) next_prio=-?\d+$')
_WAKING = re.compile(r'comm=(?P<comm>.*) pid=(?P<pid>\d+) prio=-?\d+ target_cpu=(?P<cpu>\d+)$')


class Recording:
    """perf recording the scheduler events of every CPU into `path` until stop()."""

    def __init__(self, path):
        """Start perf; its timestamps are CLOCK_MONOTONIC (time.monotonic_ns())."""
        if shutil.which('perf') is None:
            raise SystemExit('--sched-trace needs perf (Debian: apt install linux-perf)')
        self.path = path
        self._perf = subprocess.Popen(
            ['perf', 'record', '--quiet', '--all-cpus', '--clockid', 'CLOCK_MONOTONIC',
             '--event', 'sched:sched_switch', '--event', 'sched:sched_waking',
             '--output', str(path)],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

    def stop(self):
        """End the recording; raise if perf failed."""
        self._perf.send_signal(signal.SIGINT)
        _, errors = self._perf.communicate(timeout=120)
        if self._perf.returncode not in (0, -signal.SIGINT):
            raise RuntimeError(f'perf record failed ({self._perf.returncode}): {errors.strip()}')


def events(path):
    """Return [(time ns, cpu, pid, tid, comm, event, fields)] of a recording, oldest first."""
    script = subprocess.run(
        ['perf', 'script', '--input', str(path), '--ns',
         '--fields', 'comm,pid,tid,cpu,time,event,trace'],
        capture_output=True, text=True, check=True)
    found = []
    for line in script.stdout.splitlines():
        sample = _SAMPLE.match(line)
        if sample is None:
            continue
        fields = (_SWITCH if sample['event'] == 'sched_switch' else _WAKING).match(
            sample['trace'])
        if fields is None:
            continue
        found.append((int(sample['time']) * 1_000_000_000 + int(sample['ns']),
                      int(sample['cpu']), int(sample['pid']), int(sample['tid']),
                      sample['comm'], sample['event'], fields.groupdict()))
    return found


def worker_waits(trace):
    """
    Return [(woken ns, ns until it ran)] of every kernel worker's wake-up, in order.

    A pseudo-terminal's or a serial port's bytes reach their reader through a kernel worker
    (the tty layer's flip buffer work), which runs at normal priority.
    """
    woken, waits = {}, []
    for time_ns, _, _, _, _, event, fields in trace:
        if event == 'sched_waking':
            if fields['comm'].startswith('kworker/'):
                woken.setdefault(int(fields['pid']), time_ns)
        else:
            started = woken.pop(int(fields['next']), None)
            if started is not None:
                waits.append((started, time_ns - started))
    return waits


def loop_intervals(trace, driver_pid, simulator_pid):
    """
    Return the loop thread's states as (start ns, end ns, state, what ran instead) in order.

    trace: what events() yields. The loop thread is the driver's thread named LOOP_THREAD.
    """
    running_on = {}  # cpu -> comm of the task on it
    intervals, loop_tid = [], None
    since, state, ahead = None, None, None

    def enter(time_ns, new_state, new_ahead=None):
        nonlocal since, state, ahead
        if state is not None:
            intervals.append((since, time_ns, state, ahead))
        since, state, ahead = time_ns, new_state, new_ahead

    for time_ns, cpu, pid, tid, comm, event, fields in trace:
        if event == 'sched_switch':
            running_on[cpu] = fields['next_comm']
            if loop_tid is None and pid == driver_pid and comm == LOOP_THREAD:
                loop_tid = tid
            if int(fields['prev']) == loop_tid:
                if fields['state'].startswith('R'):  # preempted: still ready
                    enter(time_ns, WAITING, fields['next_comm'])
                else:
                    enter(time_ns, 'asleep')
            if loop_tid is not None and int(fields['next']) == loop_tid:
                enter(time_ns, RUNNING)
        elif loop_tid is not None and int(fields['pid']) == loop_tid and state == 'asleep':
            if pid == simulator_pid:
                waker = 'simulator'
            elif comm.startswith('kworker'):
                waker = 'kernel worker'
            elif pid == driver_pid:
                waker = 'driver thread'
            else:
                waker = 'timer or other'
            # The sleep ends at the waking; the wait for a CPU follows.
            intervals.append((since, time_ns, f'asleep, woken by {waker}', None))
            target = int(fields['cpu'])
            since, state, ahead = time_ns, WAITING, running_on.get(target)
    return intervals


def split_gaps(intervals, gaps):
    """
    Return, for each (start, end) gap in order, the ns of the loop's intervals within it.

    Each is a Counter: by state, and by ('ahead', comm) for the task that ran while it waited.
    """
    splits, first = [], 0
    for start, end in gaps:
        while first < len(intervals) and intervals[first][1] <= start:
            first += 1
        split = collections.Counter()
        for i_start, i_end, state, ahead in intervals[first:]:
            if i_start >= end:
                break
            overlap = min(i_end, end) - max(i_start, start)
            split[state] += overlap
            if ahead is not None:
                split[('ahead', ahead)] += overlap
        splits.append(split)
    return splits


def summarize(path, command_times_ns, driver_pid, simulator_pid):
    """
    Split the device's gaps (command_times_ns: monotonic, sorted) by the loop's states.

    mean_ms_all / mean_ms_slow: mean milliseconds per gap in each state; slow_gaps_by_excess:
    how many slow gaps had their largest excess over the mean in each state; ahead_ms: the
    tasks that ran while the loop waited for a CPU in the slow gaps, milliseconds each;
    worker_wait_ms: mean milliseconds per gap (all, slow) that the kernel workers woken in it
    waited for a CPU; worker_wait_percentiles_ms: of each such wait.
    """
    trace = events(path)
    intervals = loop_intervals(trace, driver_pid, simulator_pid)
    if not intervals:
        raise RuntimeError(f'no {LOOP_THREAD} thread of process {driver_pid} in {path}')
    gaps = [(a, b) for a, b in zip(command_times_ns[:-1], command_times_ns[1:])
            if a >= intervals[0][0] and b <= intervals[-1][1]]
    splits = split_gaps(intervals, gaps)
    slow = [i for i, (a, b) in enumerate(gaps) if b - a > SLOW_GAP_MS * 1e6]

    def mean_ms(indices):
        return {state: sum(splits[i][state] for i in indices) / max(len(indices), 1) / 1e6
                for state in STATES}
    mean_all = mean_ms(range(len(gaps)))
    by_excess = collections.Counter(
        max(STATES, key=lambda state: splits[i][state] / 1e6 - mean_all[state]) for i in slow)
    waits = worker_waits(trace)
    starts = [start for start, _ in waits]

    def worker_ms(indices):
        """Mean ms per gap that kernel workers woken in the gap waited for a CPU."""
        total = 0
        for i in indices:
            first, last = (bisect.bisect_left(starts, t) for t in gaps[i])
            total += sum(wait for _, wait in waits[first:last])
        return total / max(len(indices), 1) / 1e6
    in_gaps = [wait for start, wait in waits if gaps and gaps[0][0] <= start < gaps[-1][1]]
    ahead = collections.Counter()
    for i in slow:
        ahead.update({key[1]: ns / 1e6 for key, ns in splits[i].items()
                      if isinstance(key, tuple)})
    return {'gaps': len(gaps), 'slow_gaps': len(slow), 'mean_ms_all': mean_all,
            'mean_ms_slow': mean_ms(slow), 'slow_gaps_by_excess': dict(by_excess),
            'ahead_ms': dict(ahead.most_common(5)),
            'worker_wait_ms': {'all': worker_ms(range(len(gaps))), 'slow': worker_ms(slow)},
            'worker_wait_percentiles_ms': dict(zip(
                ('median', 'p99', 'max'),
                (float(np.percentile(in_gaps, q)) / 1e6 for q in (50, 99, 100))
                if in_gaps else (None, None, None)))}
