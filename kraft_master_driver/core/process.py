# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
What every long-running process of the package does about its parent: stop when it dies.

A launch, `ros2 run` or the demo that is killed (SIGKILL, a crash) cannot stop what it started,
and a driver left running holds the serial port and the device. Linux's parent-death signal has
the kernel send SIGTERM instead, which each process takes as a request to stop.
"""
import ctypes
import os
import signal
import sys

PR_SET_PDEATHSIG = 1  # from linux/prctl.h


def stop_with_parent(signum=signal.SIGTERM):
    """
    Have the kernel send `signum` to this process when its parent dies; return True if set.

    Linux only: elsewhere nothing is set and False is returned. The kernel sends it when the
    thread that started this process ends, so the parent must start it from a thread that lives
    as long as it does (launch, `ros2 run` and the demo start theirs from the main thread). A
    parent that dies between the reading of the parent's id here and the setting is caught: the
    signal is then sent at once. One that died earlier, while the interpreter was starting,
    is not.
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
