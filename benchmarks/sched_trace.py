# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Where the driver's loop thread spent the device's slow cycles, from the kernel's scheduler.

`loop.py --sched-trace` has perf record every CPU's sched_switch and sched_waking events during
a run (root, or kernel.perf_event_paranoid at -1; Debian's perf is in linux-perf). Each gap
between two commands the device received is then split by what the driver's loop thread
(kraft_loop) and the simulator's serving thread (kraft_sim) did in it:

- running on a CPU;
- ready, waiting for a CPU (and what ran there instead);
- asleep, by what woke it: the other process, a kernel worker (a pseudo-terminal's bytes reach
  their reader through one), another thread of its own process (the interpreter lock, a DDS
  lock), or anything else (its timer, which wakes it from whatever the CPU was running).

The figures are the mean time per gap in each state, over the gaps longer than SLOW_GAP_MS and
over all gaps, and for each slow gap the state that had the most time beyond its mean. Beside
them, how long the kernel workers woken in a gap waited for a CPU, and behind what.
"""
import bisect
import collections
import re
import shutil
import signal
import subprocess

from kraft_master_driver.core.control_loop import LOOP_THREAD
from kraft_master_driver.simulation.master.serving import SERVING_THREAD
import numpy as np

SLOW_GAP_MS = 1.25
RUNNING, WAITING = 'running', 'waiting for a CPU'
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
    Return [(woken ns, ns until it ran, what ran on its CPU when woken)] of kernel workers.

    A pseudo-terminal's or a serial port's bytes reach their reader through a kernel worker
    (the tty layer's flip buffer work), which runs at normal priority.
    """
    running_on, woken, waits = {}, {}, []
    for time_ns, cpu, _, _, _, event, fields in trace:
        if event == 'sched_waking':
            if fields['comm'].startswith('kworker/'):
                woken.setdefault(int(fields['pid']),
                                 (time_ns, running_on.get(int(fields['cpu']))))
        else:
            running_on[cpu] = fields['next_comm']
            started = woken.pop(int(fields['next']), None)
            if started is not None:
                waits.append((started[0], time_ns - started[0], started[1]))
    return waits


def thread_intervals(trace, pid, name, wakers):
    """
    Return the states of process pid's thread `name` as (start ns, end ns, state, ahead).

    trace: what events() yields; wakers: {pid: label} of the processes whose wakings of it are
    told apart (a kernel worker's are 'kernel worker', any other 'timer or other'). ahead: the
    task that ran while it waited for a CPU (None in the other states).
    """
    running_on = {}  # cpu -> comm of the task on it
    intervals, tid = [], None
    since, state, ahead = None, None, None

    def enter(time_ns, new_state, new_ahead=None):
        nonlocal since, state, ahead
        if state is not None:
            intervals.append((since, time_ns, state, ahead))
        since, state, ahead = time_ns, new_state, new_ahead

    for time_ns, cpu, sample_pid, sample_tid, comm, event, fields in trace:
        if event == 'sched_switch':
            running_on[cpu] = fields['next_comm']
            if tid is None and sample_pid == pid and comm == name:
                tid = sample_tid
            if int(fields['prev']) == tid:
                if fields['state'].startswith('R'):  # preempted: still ready
                    enter(time_ns, WAITING, fields['next_comm'])
                else:
                    enter(time_ns, 'asleep')
            if tid is not None and int(fields['next']) == tid:
                enter(time_ns, RUNNING)
        elif tid is not None and int(fields['pid']) == tid and state == 'asleep':
            waker = wakers.get(sample_pid) or (
                'kernel worker' if comm.startswith('kworker') else 'timer or other')
            # The sleep ends at the waking; the wait for a CPU follows.
            intervals.append((since, time_ns, f'asleep, woken by {waker}', None))
            since, state, ahead = time_ns, WAITING, running_on.get(int(fields['cpu']))
    return intervals


def split_gaps(intervals, gaps):
    """
    Return, for each (start, end) gap in order, the ns of the intervals within it.

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


def thread_figures(intervals, gaps, slow):
    """
    Return one thread's figures over the gaps; slow: the indices of the slow gaps.

    None if the thread is not in the trace. mean_ms_all / mean_ms_slow: mean milliseconds per
    gap in each state; slow_gaps_by_excess: how many slow gaps had their largest excess over
    the mean in each state; ahead_ms: the tasks that ran while it waited for a CPU in the slow
    gaps, milliseconds each.
    """
    if not intervals:
        return None
    splits = split_gaps(intervals, gaps)
    seen = {key for split in splits for key in split if isinstance(key, str)}
    states = [state for state in (RUNNING, WAITING) if state in seen] + sorted(
        seen - {RUNNING, WAITING, 'asleep'})

    def mean_ms(indices):
        return {state: sum(splits[i][state] for i in indices) / max(len(indices), 1) / 1e6
                for state in states}
    mean_all = mean_ms(range(len(gaps)))
    by_excess = collections.Counter(
        max(states, key=lambda state: splits[i][state] / 1e6 - mean_all[state]) for i in slow)
    ahead = collections.Counter()
    for i in slow:
        ahead.update({key[1]: ns / 1e6 for key, ns in splits[i].items()
                      if isinstance(key, tuple)})
    return {'mean_ms_all': mean_all, 'mean_ms_slow': mean_ms(slow),
            'slow_gaps_by_excess': dict(by_excess.most_common()),
            'ahead_ms': dict(ahead.most_common(5))}


def worker_figures(waits, gaps, slow):
    """
    Return how long the kernel workers woken in the gaps waited for a CPU.

    wait_ms: mean milliseconds per gap (all, slow); ahead_ms: what ran on their CPU when they
    were woken in the slow gaps (the waits' ms each); percentiles_ms: of each wait.
    """
    starts = [start for start, _, _ in waits]
    ahead = collections.Counter()

    def wait_ms(indices, note_ahead=False):
        total = 0
        for i in indices:
            first, last = (bisect.bisect_left(starts, t) for t in gaps[i])
            for _, wait, task in waits[first:last]:
                total += wait
                if note_ahead and task is not None:
                    ahead[task] += wait / 1e6
        return total / max(len(indices), 1) / 1e6
    each = [wait for start, wait, _ in waits if gaps and gaps[0][0] <= start < gaps[-1][1]]
    return {'wait_ms': {'all': wait_ms(range(len(gaps))), 'slow': wait_ms(slow, True)},
            'ahead_ms': dict(ahead.most_common(5)),
            'percentiles_ms': dict(zip(
                ('median', 'p99', 'max'),
                (float(np.percentile(each, q)) / 1e6 for q in (50, 99, 100))
                if each else (None, None, None)))}


def summarize(path, command_times_ns, driver_pid, simulator_pid):
    """
    Split the device's gaps (command_times_ns: monotonic, sorted) by what each thread did.

    Returns {'gaps', 'slow_gaps', 'loop': thread_figures, 'simulator': thread_figures,
    'workers': worker_figures}.
    """
    trace = events(path)
    loop = thread_intervals(trace, driver_pid, LOOP_THREAD,
                            {simulator_pid: 'simulator', driver_pid: 'driver thread'})
    if not loop:
        raise RuntimeError(f'no {LOOP_THREAD} thread of process {driver_pid} in {path}')
    serving = thread_intervals(trace, simulator_pid, SERVING_THREAD,
                               {driver_pid: 'driver', simulator_pid: 'simulator thread'})
    gaps = [(a, b) for a, b in zip(command_times_ns[:-1], command_times_ns[1:])
            if a >= loop[0][0] and b <= loop[-1][1]]
    slow = [i for i, (a, b) in enumerate(gaps) if b - a > SLOW_GAP_MS * 1e6]
    return {'gaps': len(gaps), 'slow_gaps': len(slow),
            'loop': thread_figures(loop, gaps, slow),
            'simulator': thread_figures(serving, gaps, slow),
            'workers': worker_figures(worker_waits(trace), gaps, slow)}
