# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Master and arm on two hosts (network namespaces joined by a veth pair), as on two machines.

The driver on its simulated device on one host; on the other the bridge (enabled at start),
the simulated arm behind it, started inside its soft box so that the box pushes its tool up from
the first command, and an observer (harness/remote_probe.py).
"""
import pathlib
import signal
import subprocess
import sys
import time

from harness import dds_shm, REPO
from harness.driver import executable, installed_env, next_domain_id, vector_parameter
from harness.netns import namespaces_of_this_process, NamespacesRefused, TwoHosts
from harness.remote_probe import assert_the_box_pushes_the_master, run_probe
from kraft_master_driver.nodes.slave_sim import PARAMETERS as ARM_PARAMETERS
import pytest

TESTS = REPO / 'test'  # the directory of the harness package, on the tests' path
# The arm's tool starts at the centre of its soft box, which pushes it up (+z) out of the
# nearest face harder than its servo holds it back: a steady contact force from the start.
ARM = [('start_position', vector_parameter(ARM_PARAMETERS['box.centre'][0]))]
# Enabled at start, with the master where it rests; timeouts that a loaded machine's stalls
# across the veth do not trip (a stale F/T reading is a FAULT, which zeroes the wrench).
BRIDGE = [('enable_at_start', 'true'), ('master_timeout', 2.0), ('arm_timeout', 2.0),
          ('ft_timeout', 2.0)]


def listed_namespaces():
    """Return the names `ip netns list` shows."""
    out = subprocess.run(['ip', 'netns', 'list'], capture_output=True, text=True).stdout
    return {line.split(' ')[0] for line in out.splitlines()}


@pytest.fixture
def hosts():
    """Yield (master host, slave host); skip where this machine refuses namespaces."""
    pair = TwoHosts()
    try:
        created = pair.__enter__()
    except NamespacesRefused as error:
        pytest.skip(str(error))
    try:
        yield created
    finally:
        pair.__exit__(None, None, None)
        assert not set(namespaces_of_this_process())


def start(host, prefix, domain_id, name, parameters):
    """Start installed executable `name` in `host` with `-p` parameters, output piped."""
    command = [executable(prefix, name), '--ros-args']
    for parameter, value in parameters:
        command += ['-p', f'{parameter}:={value}']
    return host.popen(command, env=host.ros_env(domain_id, installed_env(prefix, domain_id)),
                      stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def start_arm_side(host, prefix, domain_id):
    """Start the bridge and the simulated arm in `host`; return the two processes."""
    return (start(host, prefix, domain_id, 'kraft_master_teleop', BRIDGE),
            start(host, prefix, domain_id, 'kraft_master_slave_sim', ARM))


def probe(host, prefix, domain_id):
    """Run remote_probe.py in `host` to its end; return {'pose', 'wrench', 'effort': [...]}."""
    return run_probe(host, host.ros_env(domain_id, installed_env(prefix, domain_id)))


def outputs(processes):
    """Stop started processes and return their output, for a failing assertion's message."""
    texts = []
    for name, process in processes.items():
        dds_shm.end(process)
        texts.append(f'{name}:\n{process.communicate(timeout=10)[0]}')
    return '\n'.join(texts)


def test_driver_and_bridge_on_two_hosts_exchange_pose_and_wrench_across_the_veth(
        hosts, install_prefix):
    master, slave = hosts
    domain_id = next_domain_id()
    driver = start(master, install_prefix, domain_id, 'kraft_master_node',
                   [('port', 'sim'), ('force_enabled_at_start', 'true')])
    bridge, arm = start_arm_side(slave, install_prefix, domain_id)
    before = master.link_counters()
    try:
        seen = probe(slave, install_prefix, domain_id)
    except AssertionError as error:
        started = {'driver': driver, 'bridge': bridge, 'arm': arm}
        raise AssertionError(f'{error}\n{outputs(started)}') from None
    after = master.link_counters()
    assert seen['pose'][0] >= 50
    print(seen)
    assert_the_box_pushes_the_master(seen)
    # The 50 poses (about 100 bytes each) left host a on its veth, the wrenches came in on it.
    assert after[1] - before[1] > 50 * 100 and after[0] > before[0]
    assert driver.poll() is None


def test_link_emulator_between_the_hosts_delays_the_pose(hosts, install_prefix):
    master, slave = hosts
    master_domain, slave_domain = next_domain_id(), next_domain_id()
    start(master, install_prefix, master_domain, 'kraft_master_node',
          [('port', 'sim'), ('force_enabled_at_start', 'true')])
    emulator = start(master, install_prefix, master_domain, 'kraft_master_link_emulator',
                     [('slave_domain_id', slave_domain), ('to_slave.delay', 0.05),
                      ('to_master.delay', 0.03),
                      # The probe reads the torques the driver reports: relay them too.
                      ('to_slave.topics', "['pose', 'joint_states']")])
    bridge, arm = start_arm_side(slave, install_prefix, slave_domain)
    try:
        seen = probe(slave, install_prefix, slave_domain)
    except AssertionError as error:
        started = {'emulator': emulator, 'bridge': bridge, 'arm': arm}
        raise AssertionError(f'{error}\n{outputs(started)}') from None
    # Never earlier than the emulated delay; the bridge's wrench crossed back to the driver.
    assert seen['pose'][1] > 0.05
    print(seen)
    assert_the_box_pushes_the_master(seen)
    emulator.send_signal(signal.SIGINT)
    output = emulator.communicate(timeout=30)[0]
    assert emulator.returncode == 0, output
    assert 'to_master: received' in output and ', dropped 0' in output


def running(pid):
    """Return True if process `pid` exists and is not a zombie waiting to be reaped."""
    try:
        stat = pathlib.Path(f'/proc/{pid}/stat').read_text()
    except FileNotFoundError:
        return False
    return stat.rpartition(')')[2].split()[0] != 'Z'


SIGNALLED_RUN = """
import sys, time
sys.path.insert(0, {tests!r})
from harness.netns import TwoHosts
with TwoHosts() as (a, b):
    a.popen(['sleep', '600'])
    print(a.name, b.name, flush=True)
    time.sleep(600)
"""


def test_a_terminated_run_deletes_its_namespaces_and_processes():
    run = subprocess.Popen([sys.executable, '-c', SIGNALLED_RUN.format(tests=str(TESTS))],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    names = run.stdout.readline().split()
    if not names:
        error = run.communicate(timeout=30)[1]
        if 'NamespacesRefused' in error:
            pytest.skip(error.strip().splitlines()[-1])
        raise AssertionError(error)
    assert set(names) <= listed_namespaces()
    # `ip netns exec` enters the namespace some time after the run printed the names.
    deadline = time.monotonic() + 30.0
    sleeper = []
    while not sleeper and time.monotonic() < deadline:
        sleeper = subprocess.run(['ip', 'netns', 'pids', names[0]], capture_output=True,
                                 text=True).stdout.split()
    assert sleeper
    run.send_signal(signal.SIGTERM)
    run.communicate(timeout=60)
    assert run.returncode == -signal.SIGTERM
    assert not set(names) & listed_namespaces()
    assert not running(int(sleeper[0]))


def test_namespaces_of_a_dead_run_are_deleted_by_the_next_run(hosts):
    gone = subprocess.Popen(['true'])
    gone.wait()
    stale = f'kmdh{gone.pid}x0a'
    subprocess.run(['ip', 'netns', 'add', stale], check=True)
    try:
        with TwoHosts():
            assert stale not in listed_namespaces()
    finally:
        subprocess.run(['ip', 'netns', 'delete', stale], capture_output=True)


def test_without_cap_net_admin_the_harness_refuses_with_the_reason():
    # A new user namespace has no capability over this network namespace.
    result = subprocess.run(
        ['unshare', '-U', sys.executable, '-c',
         f'import sys; sys.path.insert(0, {str(TESTS)!r}); from harness import netns\n'
         'try:\n    netns.TwoHosts().__enter__()\n'
         'except netns.NamespacesRefused as error:\n    print(error)'],
        capture_output=True, text=True, timeout=60)
    assert result.stdout.startswith(
        'cannot create a network namespace (needs CAP_NET_ADMIN)'), result.stderr
