# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
What a real-time thread asks of Linux: SCHED_FIFO, and memory that is never paged out.

Each function returns None when granted, or why not in a few words (the caller says it once).
"""
from collections.abc import Callable
import ctypes
import ctypes.util
import errno
import os
import sys
import threading
from typing import NamedTuple

# <sys/mman.h>: lock what is mapped now, what is mapped later, each page once first touched
# (not the whole 800 MB of address space a ROS process reserves, up front).
MCL_CURRENT, MCL_FUTURE, MCL_ONFAULT = 1, 2, 4
PR_SET_NAME = 15  # <linux/prctl.h>
PRIORITY_FIX = ('allow it with an rtprio limit (a line "@realtime - rtprio 98" in '
                '/etc/security/limits.conf and the user in the realtime group) or CAP_SYS_NICE')
MEMLOCK_FIX = ('allow it with a memlock limit ("@realtime - memlock unlimited" in '
               '/etc/security/limits.conf) or CAP_IPC_LOCK')


def set_fifo_priority(priority: int, thread_id: int = 0) -> str | None:
    """Run a thread (0: the calling one) SCHED_FIFO at `priority`; None, or why not."""
    try:
        os.sched_setscheduler(thread_id, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as error:
        return str(error)
    return None


def name_this_thread(name: str) -> None:
    """Give the calling thread `name` in ps -L, top and perf too (Linux; its first 15 bytes)."""
    if sys.platform.startswith('linux'):
        ctypes.CDLL(None).prctl(PR_SET_NAME, name.encode()[:15], 0, 0, 0)


class NamedThread(threading.Thread):
    """A thread whose name ps -L, top and perf show too, as Python's own."""

    def run(self) -> None:
        """Name the OS thread, then run the target."""
        name_this_thread(self.name)
        super().run()


def lock_memory() -> str | None:
    """Keep every page of this process in RAM once touched (mlockall); None, or why not."""
    libc = ctypes.CDLL(ctypes.util.find_library('c'), use_errno=True)
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT) == 0:
        return None
    code = ctypes.get_errno()
    return f'[Errno {code}] {os.strerror(code)} ({errno.errorcode.get(code, "?")})'


class Scheduling(NamedTuple):
    """What a thread got of what it asked, in words for diagnostics."""

    thread: str = 'normal'
    executor: str = 'normal'
    memory_lock: str = 'not locked'


def make_real_time(priority: int, executor_thread: int | None, warn: Callable[[str], object],
                   parameter: str, thread: str) -> Scheduling:
    """
    Run the calling thread SCHED_FIFO at `priority`, `executor_thread` one below; lock memory.

    The executor's thread (a native id, or None) shares the interpreter lock with the calling
    one: at normal priority, preempted by other work while it holds the lock, it stalls the
    real-time thread. Each refusal is said once through `warn`, naming `parameter` and the
    calling `thread` (in words). Returns the Scheduling granted.
    """
    refused = set_fifo_priority(priority)
    if refused:
        warn(f'{parameter} {priority}: real-time scheduling refused ({refused}); {thread} runs '
             f'at normal priority ({PRIORITY_FIX}; or set {parameter} 0 to silence this)')
        return Scheduling(thread=f'normal ({refused})')
    executor = 'normal'
    if executor_thread is not None:
        below = max(1, priority - 1)
        refused = set_fifo_priority(below, executor_thread)
        executor = f'SCHED_FIFO {below}' if refused is None else f'normal ({refused})'
    refused = lock_memory()
    if refused:
        warn(f'memory lock refused ({refused}): a page fault may delay a cycle ({MEMLOCK_FIX})')
    return Scheduling(f'SCHED_FIFO {priority}', executor,
                      'locked' if refused is None else f'not locked ({refused})')
