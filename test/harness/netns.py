# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Two hosts on one machine: two network namespaces joined by a veth pair.

    with TwoHosts() as (master, slave):
        driver = master.popen([...], env=master.ros_env(domain_id))
        slave.popen([...], env=slave.ros_env(domain_id))

Each Host has `name` (its namespace), `address` (its end of the veth), `peer` (the other
end's address), `ros_env(domain_id)` (the environment a user sets on two real machines:
ROS_DOMAIN_ID shared, ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET, ROS_STATIC_PEERS=<peer>), and
`popen`/`run` (subprocess calls run inside the namespace through `ip netns exec`), and
`entered()` (the calling thread inside the namespace: a socket it opens stays there). The
namespaces have only loopback and the veth (with the multicast route a machine's default route
gives), so nothing reaches an address outside them.

Checked here (rclpy and Fast DDS from PyPI, 200 messages of 2 kB): SUBNET with the peer as a
static peer delivers all of them across the veth; LOCALHOST with the same static peer and Fast
DDS's default transports discovered the peer but delivered none.

Whatever way a run ends (exception, SIGTERM, SIGINT, interpreter exit), the processes started in
the namespaces are killed and the namespaces deleted, which deletes the veth pair. Namespaces
left by dead runs (found by name, `kmdh<pid>...`) are deleted when a new run starts.
TwoHosts raises NamespacesRefused with the reason where the machine does not allow them.
"""
import atexit
import contextlib
import ctypes
import itertools
import os
import re
import signal
import subprocess
import time

SUBNET = '10.231.7.'  # /24 on the veth; only the two namespaces see it
NAME_PREFIX = 'kmdh'
NAME_PATTERN = re.compile(rf'^{NAME_PREFIX}(\d+)x\d+[ab]$')
CLONE_NEWNET = 0x40000000
_runs = itertools.count()
_live = {}  # namespace name -> Host, for the exit and signal handlers


class NamespacesRefused(RuntimeError):
    """This machine does not let us create network namespaces (the reason is the message)."""


def _ip(*args, check=True):
    result = subprocess.run(['ip', *args], capture_output=True, text=True, timeout=30)
    if check and result.returncode != 0:
        raise RuntimeError(f'ip {" ".join(args)}: {result.stderr.strip()}')
    return result


def _setns(fd):
    """Move the calling thread into the network namespace open as `fd` (os.setns of 3.12)."""
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.setns(fd, CLONE_NEWNET) != 0:
        error = ctypes.get_errno()
        raise OSError(error, f'setns: {os.strerror(error)}')


def _pid_alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _kill_and_delete(name):
    """Kill every process inside namespace `name`, then delete it (and so its veth end)."""
    pids = _ip('netns', 'pids', name, check=False).stdout.split()
    for pid in pids:
        try:
            os.kill(int(pid), signal.SIGKILL)
        except ProcessLookupError:
            pass
    deadline = time.monotonic() + 10.0
    while pids and time.monotonic() < deadline:
        pids = _ip('netns', 'pids', name, check=False).stdout.split()
        time.sleep(0.01)
    _ip('netns', 'delete', name, check=False)


def delete_stale():
    """Delete namespaces of earlier runs whose process is gone; return their names."""
    listed = _ip('netns', 'list', check=False).stdout.split('\n')
    stale = []
    for line in listed:
        name = line.split(' ')[0]
        match = NAME_PATTERN.match(name)
        if match and not _pid_alive(int(match.group(1))):
            _kill_and_delete(name)
            stale.append(name)
    return stale


def namespaces_of_this_process():
    """Return the names of the namespaces this process has created and not yet deleted."""
    listed = _ip('netns', 'list', check=False).stdout.split('\n')
    names = (line.split(' ')[0] for line in listed)
    return [n for n in names if (m := NAME_PATTERN.match(n)) and int(m.group(1)) == os.getpid()]


def _cleanup_all():
    for name in list(_live):
        _kill_and_delete(name)
        _live.pop(name, None)


def _on_signal(signum, frame):
    # SIGINT needs no handler: KeyboardInterrupt leaves the `with` block through __exit__.
    _cleanup_all()
    signal.signal(signum, signal.SIG_DFL)
    os.kill(os.getpid(), signum)


atexit.register(_cleanup_all)


class Host:
    """One side of the pair: a namespace with an address on the veth."""

    def __init__(self, name, address, peer):
        """Name the namespace; `address` is this end of the veth, `peer` the other end."""
        self.name = name
        self.address = address
        self.peer = peer
        self.processes = []

    def ros_env(self, domain_id, base=None):
        """Return `base` (default os.environ) set up as on a machine that talks to the peer."""
        env = dict(os.environ if base is None else base)
        env.update({
            'ROS_DOMAIN_ID': str(domain_id),
            'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET',
            'ROS_STATIC_PEERS': self.peer,
            # Both namespaces share /dev/shm: without this Fast DDS would hand samples between
            # them through shared memory, not across the veth as between two machines.
            'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4',
            'PYTHONUNBUFFERED': '1',
        })
        return env

    def command(self, args):
        """Return `args` prefixed so that they run inside this namespace."""
        return ['ip', 'netns', 'exec', self.name, *map(str, args)]

    def popen(self, args, **kwargs):
        """Start `args` inside this namespace (subprocess.Popen keywords); killed at the end."""
        process = subprocess.Popen(self.command(args), **kwargs)
        self.processes.append(process)
        return process

    def run(self, args, **kwargs):
        """Run `args` inside this namespace to the end (subprocess.run keywords)."""
        return subprocess.run(self.command(args), **kwargs)

    @contextlib.contextmanager
    def entered(self):
        """Run the calling thread inside this namespace for the `with` block, then return."""
        own = os.open('/proc/thread-self/ns/net', os.O_RDONLY)
        try:
            target = os.open(f'/var/run/netns/{self.name}', os.O_RDONLY)
            try:
                _setns(target)
            finally:
                os.close(target)
            try:
                yield self
            finally:
                _setns(own)
        finally:
            os.close(own)

    def link_counters(self):
        """Return (rx_bytes, tx_bytes) of this end of the veth."""
        out = self.run(['cat', '/proc/net/dev'], capture_output=True, text=True, check=True)
        for line in out.stdout.splitlines():
            name, _, fields = line.partition(':')
            if name.strip().startswith('veth'):
                values = fields.split()
                return int(values[0]), int(values[8])
        raise RuntimeError(f'no veth in namespace {self.name}')


class TwoHosts:
    """Context manager: two namespaces joined by a veth pair; yields (host_a, host_b)."""

    def __init__(self):
        """Choose names unique to this process and run."""
        tag = f'{NAME_PREFIX}{os.getpid()}x{next(_runs)}'
        self.hosts = (Host(tag + 'a', SUBNET + '1', SUBNET + '2'),
                      Host(tag + 'b', SUBNET + '2', SUBNET + '1'))
        self._previous_handlers = {}

    def __enter__(self):
        """Create both namespaces and the veth pair; raise NamespacesRefused if not allowed."""
        delete_stale()
        for sig in (signal.SIGTERM, signal.SIGHUP):
            self._previous_handlers[sig] = signal.signal(sig, _on_signal)
        try:
            self._create()
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self.hosts

    def _create(self):
        a, b = self.hosts
        first = _ip('netns', 'add', a.name, check=False)
        if first.returncode != 0:
            raise NamespacesRefused(
                f'cannot create a network namespace (needs CAP_NET_ADMIN): '
                f'{first.stderr.strip()}')
        _live[a.name] = a
        _ip('netns', 'add', b.name)
        _live[b.name] = b
        # The veth is created inside namespace a, so it never appears where we run.
        _ip('-n', a.name, 'link', 'add', 'veth0', 'type', 'veth', 'peer', 'name', 'veth0',
            'netns', b.name)
        for host in self.hosts:
            _ip('-n', host.name, 'addr', 'add', host.address + '/24', 'dev', 'veth0')
            _ip('-n', host.name, 'link', 'set', 'lo', 'up')
            _ip('-n', host.name, 'link', 'set', 'veth0', 'up')
            _ip('-n', host.name, 'route', 'add', '224.0.0.0/4', 'dev', 'veth0')

    def __exit__(self, *exc):
        """End the processes of both hosts and delete the namespaces (and so the veth)."""
        for host in self.hosts:
            for process in host.processes:
                if process.poll() is None:
                    process.terminate()  # not SIGKILL: DDS removes its shared memory
        for host in self.hosts:
            for process in host.processes:
                try:
                    process.communicate(timeout=10)
                except (subprocess.TimeoutExpired, ValueError):
                    pass
            if host.name in _live:
                _kill_and_delete(host.name)
                _live.pop(host.name, None)
        for sig, handler in self._previous_handlers.items():
            signal.signal(sig, handler)
        self._previous_handlers.clear()
        return False
