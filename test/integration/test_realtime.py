# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""A real-time station: what the driver and the bridge ask of Linux, and the Fast DDS profile."""
import os
import pathlib

from diagnostic_msgs.msg import DiagnosticArray
from harness import PACKAGE
from harness.driver import DriverProcess, next_domain_id, RosClient
import pytest

pytestmark = pytest.mark.integration

PROFILE = pathlib.Path('share') / PACKAGE / 'config' / 'fastdds_realtime.xml'
PROFILE_PRIORITY = 50  # what config/fastdds_realtime.xml asks for its threads
WRENCH = (0.0, 0.0, 4.0, 0.0, 0.0, 0.0)


def threads_of(pid):
    """Return (name, policy, rt_priority) of each thread of process pid (Linux /proc)."""
    return [thread_of(pid, task.name) for task in pathlib.Path(f'/proc/{pid}/task').iterdir()]


def thread_of(pid, tid):
    """Return (name, policy, rt_priority) of thread tid of process pid (Linux /proc)."""
    task = pathlib.Path(f'/proc/{pid}/task/{tid}')
    fields = (task / 'stat').read_text().rsplit(')', 1)[1].split()
    return (task / 'comm').read_text().strip(), int(fields[38]), int(fields[37])


def locked_kib(pid):
    """Return the memory the process has locked (VmLck, kB)."""
    for line in pathlib.Path(f'/proc/{pid}/status').read_text().splitlines():
        if line.startswith('VmLck:'):
            return int(line.split()[1])
    raise AssertionError(f'no VmLck in /proc/{pid}/status')


def assert_real_time_at_30(process, threads_at_30):
    """
    Assert `threads_at_30` threads of `process` at SCHED_FIFO 30, and its main thread at 29.

    The main thread spins the executor, which shares the interpreter lock with the real-time
    threads. Also asserted: memory locked, and a clean exit at Ctrl-C without a refusal.
    """
    pid = process.process.pid
    threads = threads_of(pid)
    assert sum(t[1:] == (os.SCHED_FIFO, 30) for t in threads) == threads_at_30, threads
    assert thread_of(pid, pid)[1:] == (os.SCHED_FIFO, 29)
    assert locked_kib(pid) > 0
    code, output = process.interrupt()
    assert code == 0, output
    assert 'refused' not in output


def start(install_prefix, parameters, wrapper=()):
    """Start the installed driver on its built-in simulator; return (driver, client)."""
    domain_id = next_domain_id()
    driver = DriverProcess(install_prefix, domain_id, [('port', 'sim'), *parameters],
                           wrapper=wrapper)
    client = RosClient(domain_id)
    try:
        client.wait_connected()
    except AssertionError:
        client.close()
        driver.kill()
        raise
    return driver, client


def test_the_built_in_simulator_runs_at_the_loop_priority_and_memory_is_locked(install_prefix):
    driver, client = start(install_prefix, [('loop_priority', '30')])
    try:
        # The loop thread and the simulated device's serving thread, which stands in for
        # hardware that answers by itself. The loop thread carries its name in ps -L and top.
        assert ('kraft_loop', os.SCHED_FIFO, 30) in threads_of(driver.process.pid)
        assert_real_time_at_30(driver, threads_at_30=2)
    finally:
        client.close()
        driver.kill()


def test_the_fastdds_profile_runs_the_wrench_path_threads_at_its_priority(install_prefix):
    profile = install_prefix / PROFILE
    assert profile.is_file()
    wrapper = ['env', f'FASTRTPS_DEFAULT_PROFILES_FILE={profile}']
    driver, client = start(install_prefix, [('force_enabled_at_start', 'true')], wrapper)
    try:
        # A wrench from a participant without the profile still reaches the torques.
        client.stream_wrench_until(WRENCH, 'kraft_master_base', lambda: client.joint_states and
                                   any(client.joint_states[-1].effort))
        threads = threads_of(driver.process.pid)
        dds = [t for t in threads if t[0].startswith(('dds.udp.', 'dds.shm.', 'dds.ev.',
                                                      'dds.asyn.')) and t[0] != 'dds.shm.wdog']
        assert {name.split('.')[1] for name, _, _ in dds} == {'udp', 'shm', 'ev', 'asyn'}, dds
        assert all(t[1:] == (os.SCHED_FIFO, PROFILE_PRIORITY) for t in dds), dds
        code, output = driver.interrupt()
        assert code == 0, output
    finally:
        client.close()
        driver.kill()


def test_a_refused_memory_lock_is_one_warning_with_the_fix_and_the_loop_runs_on(
        install_prefix):
    without_ipc_lock = ['setpriv', '--inh-caps', '-ipc_lock', '--bounding-set', '-ipc_lock',
                        'prlimit', '--memlock=0:0']
    driver, client = start(install_prefix, [('loop_priority', '30')], without_ipc_lock)
    try:
        count = len(client.joint_states)
        client.wait(lambda: len(client.joint_states) > count + 100)
        assert locked_kib(driver.process.pid) == 0
        code, output = driver.interrupt()
        assert code == 0, output
        warnings = [line for line in output.splitlines() if 'memory lock refused' in line]
        assert len(warnings) == 1, output
        assert 'memlock' in warnings[0] and 'limits.conf' in warnings[0]
    finally:
        client.close()
        driver.kill()


def bridge_scheduling(install_prefix, wrapper=()):
    """
    Start the installed bridge with input_priority 30; return (bridge, its diagnostics' values).

    The values are those of the first diagnostics after its input thread asked for its priority.
    """
    domain_id = next_domain_id()
    bridge = DriverProcess(install_prefix, domain_id, [('input_priority', '30')],
                           name='kraft_master_teleop', wrapper=wrapper)
    client = RosClient(domain_id)
    values = []
    client.node.create_subscription(
        DiagnosticArray, '/diagnostics',
        lambda msg: values.extend({kv.key: kv.value for kv in status.values}
                                  for status in msg.status), 10)
    try:
        client.wait(lambda: any(v.get('input scheduler', 'normal') != 'normal' for v in values))
    except AssertionError:
        bridge.kill()
        raise
    finally:
        client.close()
    return bridge, next(v for v in values if v.get('input scheduler', 'normal') != 'normal')


def test_the_bridge_runs_its_input_thread_at_input_priority_and_its_executor_one_below(
        install_prefix):
    bridge, values = bridge_scheduling(install_prefix)
    try:
        assert values['input scheduler'] == 'SCHED_FIFO 30', values
        assert values['executor scheduler'] == 'SCHED_FIFO 29', values
        assert values['memory lock'] == 'locked', values
        threads = threads_of(bridge.process.pid)
        assert sum(t[1] != os.SCHED_OTHER for t in threads) == 2, threads
        assert_real_time_at_30(bridge, threads_at_30=1)
    finally:
        bridge.kill()


def test_a_refused_input_priority_is_one_warning_with_the_fix_and_the_bridge_runs_on(
        install_prefix):
    without_sys_nice = ['setpriv', '--inh-caps', '-sys_nice', '--bounding-set', '-sys_nice']
    bridge, values = bridge_scheduling(install_prefix, without_sys_nice)
    try:
        assert values['input scheduler'].startswith('normal ('), values
        assert values['executor scheduler'] == 'normal', values
        assert all(t[1] == os.SCHED_OTHER for t in threads_of(bridge.process.pid))
        code, output = bridge.interrupt()
        assert code == 0, output
        warnings = [line for line in output.splitlines() if 'real-time scheduling refused' in line]
        assert len(warnings) == 1, output
        assert 'input_priority 30' in warnings[0] and 'the input thread' in warnings[0]
        assert 'limits.conf' in warnings[0]
    finally:
        bridge.kill()
