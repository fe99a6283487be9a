# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
A command run under a subreaper: every process it starts is waited for, whoever dies first.

When the command dies (SIGKILL, SIGTERM), what it started becomes the subreaper's child instead
of init's, so that each one's exit code can still be told and none is left unseen.
"""
from glob import glob
import os
import signal
import subprocess
import sys

from harness import dds_shm
from harness.driver import AT_A_TERMINAL, WAIT_S

PR_SET_CHILD_SUBREAPER = 36  # linux/prctl.h

# Starts the command (its output to the file named first) in a session of its own, prints its
# id, then each exit as "pid code" until no child is left.
SUBREAPER = f"""
import ctypes, os, subprocess, sys
ctypes.CDLL(None).prctl({PR_SET_CHILD_SUBREAPER}, 1, 0, 0, 0)
with open(sys.argv[1], 'w') as output:
    command = subprocess.Popen(sys.argv[2:], stdout=output, stderr=subprocess.STDOUT,
                               stdin=subprocess.DEVNULL, start_new_session=True)
print(command.pid, flush=True)
while True:
    try:
        pid, status = os.wait()
    except ChildProcessError:
        break
    print(pid, os.waitstatus_to_exitcode(status), flush=True)
"""


def _read(path):
    try:
        with open(path) as file:
            return file.read()
    except OSError:  # the process or thread has just ended
        return ''


def descendants(pid):
    """Return the ids of the processes that `pid` started, and theirs, still running."""
    found = []
    parents = [pid]
    while parents:
        parent = parents.pop()
        for children in glob(f'/proc/{parent}/task/*/children'):
            for child in map(int, _read(children).split()):
                found.append(child)
                parents.append(child)
    return found


def describe(pid):
    """Return a line on a running process: its command, and each thread's state and wait."""
    # Each argument on one line and short: a `python -c` script would fill the message.
    command = ' '.join(' '.join(argument.split())[:60]
                       for argument in _read(f'/proc/{pid}/cmdline').split('\0') if argument)
    threads = []
    for task in sorted(glob(f'/proc/{pid}/task/*')):
        # stat: "tid (name) state ..."; wchan: the kernel function a sleeping thread waits in.
        name, _, rest = _read(f'{task}/stat').rpartition(')')
        threads.append(f"{name.partition('(')[2]} {rest.split()[0] if rest else '?'} "
                       f"{_read(f'{task}/wchan') or '-'}")
    return f"{pid} {command} [threads: {', '.join(threads)}]"


class Reaped:
    """`command` started by a subreaper, with its output in `log_path`."""

    def __init__(self, command, env, log_path):
        """Start it; `pid` is the command's process id, also its process group's."""
        self.log_path = log_path
        self.subreaper = subprocess.Popen(
            [sys.executable, '-c', SUBREAPER, str(log_path), *AT_A_TERMINAL, *command], env=env,
            stdout=subprocess.PIPE, text=True)
        self.pid = int(self.subreaper.stdout.readline())

    def log(self):
        """Return what the command and its children have written so far."""
        return self.log_path.read_text()

    def exits(self, timeout=WAIT_S):
        """
        Wait until every process the command started has ended; return {pid: exit code}.

        If some have not ended in `timeout` seconds, fail with what each of them is doing.
        """
        try:
            output, _ = self.subreaper.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            still_running = [describe(pid) for pid in descendants(self.subreaper.pid)]
            raise AssertionError(f'still running after {timeout:.0f} s: '
                                 + '; '.join(still_running)) from None
        return {int(pid): int(code) for pid, code in (line.split() for line in
                                                      output.splitlines())}

    def close(self):
        """End whatever is still running: SIGTERM to the command's group, then the subreaper."""
        try:
            os.killpg(self.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
        dds_shm.end(self.subreaper)
