# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
What every long-running process of the package does from its first instant.

A launch, `ros2 run` or the demo that is killed (SIGKILL, a crash) cannot stop what it started,
and a driver left running holds the serial port and the device. Linux's parent-death signal has
the kernel send SIGTERM instead, which each process takes as a request to stop.

A stop signal can also come while the process is still importing its modules (2 s on a loaded
machine): a launch stopped early, a second Ctrl-C. Python's defaults would end it with a
KeyboardInterrupt traceback (SIGINT) or kill it (SIGTERM, SIGHUP); remember_stop_signals() has
it remembered instead, so that the node, once its own handlers are in, stops as asked.

A process started with SIGHUP ignored (`nohup`) was asked to outlive its terminal: SIGHUP is then
not among its stop signals, and stays ignored.
"""
import ctypes
import os
import signal
import sys

PR_SET_PDEATHSIG = 1  # from linux/prctl.h
STOP_SIGNALS = tuple(
    signum for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    if signum != signal.SIGHUP or signal.getsignal(signal.SIGHUP) is not signal.SIG_IGN)
_remembered: list[int] = []


def remember_stop_signals() -> None:
    """Until other handlers replace this one, remember each stop signal instead of ending."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, lambda signum, _frame: _remembered.append(signum))


def stop_signal_remembered() -> bool:
    """Return True if a stop signal came while remember_stop_signals() held them."""
    return bool(_remembered)


def stop_with_parent(signum: int = signal.SIGTERM) -> bool:
    """
    Have the kernel send `signum` to this process when its parent dies; return True if set.

    Linux only: elsewhere nothing is set and False is returned. The kernel sends it when the
    thread that started this process ends, so the parent must start it from a thread that lives
    as long as it does (launch, `ros2 run` and the demo start theirs from the main thread). A
    parent that dies between the reading of the parent's id here and the setting is caught: the
    signal is then sent at once. One that died earlier is not: the nodes' console scripts call
    this first (nodes.commands), which leaves the interpreter's start and the script wrapper's
    entry-point lookup uncovered (1.3 to 3.6 s of imports on a machine loaded 10 times over).
    """
    if not sys.platform.startswith('linux'):
        return False
    parent = os.getppid()
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, int(signum), 0, 0, 0) != 0:
        return False
    if os.getppid() != parent:
        os.kill(os.getpid(), signum)
    return True
