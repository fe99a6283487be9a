# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Fast DDS's shared-memory files in /dev/shm: whose they are, and removing those left behind.

Each DDS participant maps segments (fastrtps_<16 hex>) and ports (fastrtps_port<N>, with a
semaphore sem.fastrtps_port<N>_mutex), each beside a lock file (_el or _sl) that the process
using it holds locked while it lives. A participant that tears down removes its files; one
killed with SIGKILL leaves them, unlocked: what `fastdds shm clean` removes, machine-wide.
Here only the files of a known process, or those that appeared during a test run, are touched.
"""
import os
import pathlib
import re
import signal
import subprocess
import threading

SHM_DIR = pathlib.Path('/dev/shm')
LOCK_SUFFIXES = ('_el', '_sl')
_FASTDDS_FILE = re.compile(r'^(?:sem\.)?(fastrtps_(?:port\d+|[0-9a-f]{16}))(?:_el|_sl|_mutex)?$')


def groups():
    """Return the Fast DDS segments and ports in /dev/shm by name (fastrtps_...)."""
    found = set()
    for name in os.listdir(SHM_DIR):
        match = _FASTDDS_FILE.match(name)
        if match:
            found.add(match.group(1))
    return found


def _files(group):
    return [SHM_DIR / name for name in (
        group, f'sem.{group}_mutex', *(group + suffix for suffix in LOCK_SUFFIXES))]


def _lock_owners():
    """Return {(device, inode): pids} of the file locks held (/proc/locks)."""
    owners = {}
    with open('/proc/locks') as locks:
        for line in locks:
            fields = line.split()
            if '->' in fields:  # a process waiting for the lock, not holding it
                continue
            major, minor, inode = fields[5].split(':')
            key = (os.makedev(int(major, 16), int(minor, 16)), int(inode))
            owners.setdefault(key, set()).add(int(fields[4]))
    return owners


def _lock_files(group):
    return [path for path in (SHM_DIR / (group + suffix) for suffix in LOCK_SUFFIXES)
            if path.exists()]


def _holders(group, owners):
    pids = set()
    for path in _lock_files(group):
        try:
            status = path.stat()
        except FileNotFoundError:
            continue
        pids |= owners.get((status.st_dev, status.st_ino), set())
    return pids


def held_by(pid):
    """Return the groups whose lock process `pid` holds."""
    owners = _lock_owners()
    return {group for group in groups() if pid in _holders(group, owners)}


def orphaned(candidates):
    """Return those of the `candidates` groups still there whose lock no process holds."""
    owners = _lock_owners()
    present = groups()
    return {group for group in candidates if group in present and not _holders(group, owners)}


def remove(found):
    """Remove every file of the groups `found`."""
    for group in found:
        for path in _files(group):
            try:
                path.unlink()
            except FileNotFoundError:
                pass


def kill_and_clean(process, timeout=30.0):
    """SIGKILL a subprocess.Popen and remove the shared memory it leaves."""
    held = held_by(process.pid)
    process.kill()
    process.wait(timeout)
    remove(orphaned(held))


def end(process, timeout=30.0):
    """
    End a subprocess.Popen so that its DDS participants tear down: SIGTERM, then SIGKILL.

    SIGKILL only if it has not ended within `timeout` s; what it then leaves is removed.
    """
    if process.poll() is not None:
        return
    process.send_signal(signal.SIGTERM)
    try:
        process.wait(timeout)
    except subprocess.TimeoutExpired:
        kill_and_clean(process)


def _descends_from(pid, ancestor):
    while pid > 1:
        if pid == ancestor:
            return True
        try:
            with open(f'/proc/{pid}/stat') as stat:
                pid = int(stat.read().rpartition(')')[2].split()[1])
        except (FileNotFoundError, ProcessLookupError, ValueError):
            return False
    return pid == ancestor


def _command_line(pid, longest=160):
    """Return the command line of process `pid`, cut to `longest` characters."""
    try:
        line = pathlib.Path(f'/proc/{pid}/cmdline').read_bytes().replace(b'\0', b' ')
    except (FileNotFoundError, ProcessLookupError):
        return '(gone)'
    return line.decode(errors='replace').strip()[:longest]


class Watcher(threading.Thread):
    """
    Notes, every `period` s, the new groups held by this process or one of its descendants.

    With each, whose it was when first seen: the holder's command line and pid, and the test
    that was running (pytest's PYTEST_CURRENT_TEST), so that one left behind can be traced.
    """

    def __init__(self, period=0.2):
        """Take the groups there now as not ours; call start()."""
        super().__init__(name='dds_shm_watcher', daemon=True)
        self.before = groups()
        self.ours = {}
        self._period = period
        self._stopping = threading.Event()

    def run(self):
        """Look until stop()."""
        while not self._stopping.wait(self._period):
            self.look()

    def look(self):
        """Note the new groups whose lock one of our processes holds now, and whose they are."""
        owners = _lock_owners()
        for group in groups() - self.before - self.ours.keys():
            ours = sorted(pid for pid in _holders(group, owners)
                          if _descends_from(pid, os.getpid()))
            if ours:
                test = os.environ.get('PYTEST_CURRENT_TEST', 'no test')
                self.ours[group] = f'{_command_line(ours[0])} (pid {ours[0]}) during {test}'

    def stop(self):
        """Stop looking (after a last look); return {group noted: whose it was}."""
        self._stopping.set()
        self.join()
        self.look()
        return self.ours
