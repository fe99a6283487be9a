# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""kraft_master_ctl from the venv against the installed driver on a simulated device."""
import os
import pathlib
import re
import shlex
import subprocess
import sys

from geometry_msgs.msg import TwistStamped
from harness import dds_shm, REPO
from harness.driver import DriverProcess, next_domain_id, RosClient
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
import pytest

pytestmark = pytest.mark.integration

# The venv these tests run in: .venv/ under `make test`, .venv-latest/ under `make test-latest`.
BIN = pathlib.Path(sys.executable).parent
CTL = BIN / 'kraft_master_ctl'
NAMESPACE = '/right'
WRENCH = (0.0, 0.0, -5.0, 0.0, 0.0, 0.0)


def user_env(domain_id):
    """Return this environment as a user's shell has it (no PYTHONPATH), on one DDS domain."""
    env = {k: v for k, v in os.environ.items() if k != 'PYTHONPATH'}
    env.update(ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    return env


def ctl(domain_id, *args, cwd):
    """Run kraft_master_ctl as a user would, outside the repository; return the result."""
    return subprocess.run([str(CTL), *args], cwd=cwd, env=user_env(domain_id),
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120)


def in_this_venv(command):
    """Return a command of the page as arguments, with its `.venv/bin/` the tests' venv."""
    arguments = shlex.split(command)
    venv_bin = '.venv/bin/'
    if arguments[0].startswith(venv_bin):
        arguments[0] = str(BIN / arguments[0][len(venv_bin):])
    return arguments


def test_the_readme_venv_commands_work_as_typed():
    """The block of doc/getting-started.md on the venv's commands, line by line, from the repo."""
    section = (REPO / 'doc' / 'getting-started.md').read_text().partition(
        '### The commands in the venv')[2]
    lines = re.search(r'^```\n(.*?)^```', section, re.MULTILINE | re.DOTALL).group(1)
    env = user_env(next_domain_id())
    driver = None
    try:
        for line in lines.splitlines():
            command = line.partition('  #')[0].strip()
            if command.endswith('&'):
                driver = subprocess.Popen(
                    in_this_venv(command[:-1]), cwd=REPO, env=env, stdin=subprocess.DEVNULL,
                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            elif command == 'kill %1':
                driver.terminate()
                output, _ = driver.communicate(timeout=60)
                assert driver.returncode == 0, output
            else:
                result = subprocess.run(in_this_venv(command), cwd=REPO, env=env,
                                        stdin=subprocess.DEVNULL, capture_output=True,
                                        text=True, timeout=120)
                assert result.returncode == 0, f'{command}\n{result.stdout}{result.stderr}'
        assert driver is not None and driver.returncode == 0
    finally:
        if driver is not None:
            dds_shm.end(driver)
            driver.communicate()


@pytest.fixture
def driver(install_prefix):
    """Yield (domain id, simulator, client) of a driver in /right with rate_command on."""
    domain_id = next_domain_id()
    simulator = SimulatedKraftMaster(arm='right', operator='hold')
    parameters = [('port', simulator.start()), ('rate_command_enabled', 'true')]
    process = DriverProcess(install_prefix, domain_id, parameters, namespace=NAMESPACE)
    client = RosClient(domain_id, namespace=NAMESPACE)
    rate_commands = []
    client.node.create_subscription(TwistStamped, 'rate_command', rate_commands.append, 10)
    client.rate_commands = rate_commands
    try:
        client.wait_connected()
        yield domain_id, simulator, client
    finally:
        client.close()
        process.kill()
        simulator.stop()


def test_force_on_and_off_switch_the_torques(driver, tmp_path):
    domain_id, simulator, client = driver
    client.stream_wrench(WRENCH, 'kraft_master_base', seconds=0.3)
    assert not any(simulator.received[-1][1].counts), 'force output is off at start-up'

    result = ctl(domain_id, 'force', 'on', '--namespace', NAMESPACE, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout == '/right/enable_force: force output enabled\n'
    client.stream_wrench_until(WRENCH, 'kraft_master_base',
                               lambda: any(simulator.received[-1][1].counts))

    result = ctl(domain_id, 'force', 'off', '--namespace', 'right', cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout == '/right/enable_force: force output disabled\n'
    frames = len(client.joint_states)
    client.stream_wrench_until(WRENCH, 'kraft_master_base',
                               lambda: len(client.joint_states) > frames + 20)
    assert not any(simulator.received[-1][1].counts)
    assert not any(client.joint_states[-1].effort)


def test_set_center_starts_the_rate_command(driver, tmp_path):
    domain_id, _, client = driver
    client.spin(0.3)
    assert not client.rate_commands, 'no rate_command before a centre is set'
    result = ctl(domain_id, 'set_center', '--namespace', NAMESPACE, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith('/right/set_center: centre set at (')
    client.wait(lambda: len(client.rate_commands) > 5)


def test_no_driver_is_one_line_and_exit_1(tmp_path):
    result = ctl(next_domain_id(), 'force', 'on', '--namespace', '/left', '--timeout', '2',
                 cwd=tmp_path)
    assert result.returncode == 1
    assert result.stderr.startswith('kraft_master_ctl: no driver offers /left/enable_force '
                                    'within 2 s')
    assert result.stderr.count('\n') == 1 and not result.stdout


@pytest.mark.parametrize('args', [('force', 'maybe'), ('set_centre',), (),
                                  ('force', 'on', '--timeout', '-1'),
                                  ('set_center', '--namespace', '/bad name')])
def test_bad_input_is_one_line_and_exit_1(args, tmp_path):
    result = ctl(next_domain_id(), *args, cwd=tmp_path)
    assert result.returncode == 1
    assert result.stderr.startswith('kraft_master_ctl: ')
    assert result.stderr.count('\n') == 1 and not result.stdout
