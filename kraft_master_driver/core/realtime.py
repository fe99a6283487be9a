# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
What a real-time thread asks of Linux: SCHED_FIFO, and memory that is never paged out.

Each function returns None when granted, or why not in a few words (the caller says it once).
"""
import ctypes
import ctypes.util
import errno
import os

# <sys/mman.h>: lock what is mapped now, what is mapped later, each page once first touched
# (not the whole 800 MB of address space a ROS process reserves, up front).
MCL_CURRENT, MCL_FUTURE, MCL_ONFAULT = 1, 2, 4
PRIORITY_FIX = ('allow it with an rtprio limit (a line "@realtime - rtprio 98" in '
                '/etc/security/limits.conf and the user in the realtime group) or CAP_SYS_NICE')
MEMLOCK_FIX = ('allow it with a memlock limit ("@realtime - memlock unlimited" in '
               '/etc/security/limits.conf) or CAP_IPC_LOCK')


def set_fifo_priority(priority, thread_id=0):
    """Run a thread (0: the calling one) SCHED_FIFO at `priority`; None, or why not."""
    try:
        os.sched_setscheduler(thread_id, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as error:
        return str(error)
    return None


def lock_memory():
    """Keep every page of this process in RAM once touched (mlockall); None, or why not."""
    libc = ctypes.CDLL(ctypes.util.find_library('c'), use_errno=True)
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT) == 0:
        return None
    code = ctypes.get_errno()
    return f'[Errno {code}] {os.strerror(code)} ({errno.errorcode.get(code, "?")})'
