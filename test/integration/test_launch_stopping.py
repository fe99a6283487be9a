# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The launch files stopped as a user, systemd or a CI runner stops them (issue 20).

Each launch file runs through the launch API, as `ros2 launch` runs it, under a subreaper
(harness.reaper) that tells the exit of every process the launch started, also of those its
death orphans. The launch gets SIGINT (Ctrl-C at its terminal), SIGINT twice to its process
group (a terminal's Ctrl-C pressed twice, or a launch without a terminal that forwards its own),
SIGTERM (systemd, `docker stop`, `kill`), SIGHUP (its terminal closed) or SIGKILL. Whatever the
ending: every node exits 0 without a traceback, none is left, the device's last command is zero
torque, and the built-in simulator's pty directory is removed.
"""
import os
import re
import signal
import sys

from geometry_msgs.msg import Vector3Stamped
from harness.driver import installed_env, next_domain_id, RosClient, wait_for, WAIT_S
from harness.reaper import Reaped
from kraft_master_driver.core import kinematics
from kraft_master_driver.simulation.master.model import Workspace
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
from kraft_master_driver.tools.urdf_model import driver_names
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from std_srvs.srv import SetBool

NOT_HERE = ('launch and launch_ros cannot be installed on this machine: they are not on PyPI '
            '(they come with a ROS 2 install; run these tests there)')
pytest.importorskip('launch', reason=NOT_HERE)
pytest.importorskip('launch_ros.actions', reason=NOT_HERE)

pytestmark = pytest.mark.integration

WRENCH = (3.0, -2.0, 4.0, 0.05, -0.1, 0.08)
STARTED = re.compile(r'\[INFO\] \[([\w-]+)\]: process started with pid \[(\d+)\]')
# What the launch says of a process's end, while it lives to see it.
FINISHED = re.compile(r'process has finished cleanly \[pid (\d+)\]()')
DIED = re.compile(r'process has died \[pid (\d+), exit code (-?\d+)')
SIM_DIRECTORY = re.compile(r'simulated hand controller on (\S+)/tty')
# How `ros2 launch` runs a launch file with its arguments (ros2launch.api), in a process.
RUN_LAUNCH_FILE = """
import sys
import launch
from launch.actions import IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
arguments = [argument.split(':=', 1) for argument in sys.argv[2:]]
service = launch.LaunchService(argv=sys.argv[2:])
service.include_launch_description(launch.LaunchDescription([IncludeLaunchDescription(
    PythonLaunchDescriptionSource(sys.argv[1]), launch_arguments=arguments)]))
sys.exit(service.run())
"""
# (signal, to the process group?, times, the launch's own exit code). As launch 3.4.3 (jazzy)
# ends: a Ctrl-C at a terminal reaches the whole group, and launch then leaves the SIGINT to it;
# a SIGINT to the launch alone reaches its processes as SIGTERM 5 s later (sigterm_timeout).
# On SIGTERM, as on the signals it does not handle, launch dies of the signal without stopping
# its processes: its nodes then stop on their parent-death signal.
ENDINGS = {
    'Ctrl-C': (signal.SIGINT, True, 1, 0),
    'Ctrl-C twice': (signal.SIGINT, True, 2, 0),
    'SIGINT to the launch alone': (signal.SIGINT, False, 1, 0),
    'SIGTERM': (signal.SIGTERM, False, 1, -signal.SIGTERM),
    'SIGHUP': (signal.SIGHUP, False, 1, -signal.SIGHUP),
    'SIGKILL': (signal.SIGKILL, False, 1, -signal.SIGKILL),
}


def started_processes(log):
    """Return {pid: name} of the processes the launch says it started."""
    return {int(pid): name for name, pid in STARTED.findall(log)}


def end(launch, ending):
    """Send the ending's signal to the launch or its process group, once or twice."""
    sig, to_group, times, _ = ENDINGS[ending]
    for _ in range(times):
        (os.killpg if to_group else os.kill)(launch.pid, sig)


def run_launch_file(prefix, domain_id, log_path, file_name, **arguments):
    """Start the installed launch file `file_name` with `arguments` under a subreaper."""
    path = prefix / 'share' / 'kraft_master_driver' / 'launch' / file_name
    command = [sys.executable, '-c', RUN_LAUNCH_FILE, str(path),
               *(f'{name}:={value}' for name, value in arguments.items())]
    return Reaped(command, installed_env(prefix, domain_id), log_path)


def assert_every_process_ended_well(launch, ending):
    """
    Wait until no process is left; each node the launch started exited 0, without a traceback.

    A node's exit code comes from the launch if it lived to see it, else from the subreaper.
    """
    exits = launch.exits()
    log = launch.log()
    assert exits.pop(launch.pid) == ENDINGS[ending][3], log
    for pattern in (FINISHED, DIED):
        exits.update((int(pid), int(code or 0)) for pid, code in pattern.findall(log))
    nodes = started_processes(log)
    assert nodes, log
    assert exits == dict.fromkeys(nodes, 0), log
    assert 'Traceback' not in log, log


@pytest.mark.parametrize('ending', ENDINGS)
def test_a_stopped_launch_of_two_drivers_leaves_zero_torque_and_nothing_running(
        install_prefix, tmp_path, ending):
    domain_id = next_domain_id()
    simulator = SimulatedKraftMaster(arm='right', operator='hold')
    client = RosClient(domain_id, namespace='/right')
    launch = run_launch_file(install_prefix, domain_id, tmp_path / 'launch.log',
                             'kraft_master.launch.py', arms='both', force_enabled='true',
                             right_port=simulator.start(), left_port='sim')
    try:
        client.wait_connected()
        client.stream_wrench_until(WRENCH, driver_names('right')['base_frame'],
                                   lambda: any(simulator.received[-1][1].counts))
        directory = wait_for(lambda: SIM_DIRECTORY.search(launch.log()))[1]
        wait_for(lambda: len(started_processes(launch.log())) == 2)
        end(launch, ending)
        assert_every_process_ended_well(launch, ending)
        wait_for(lambda: not any(simulator.received[-1][1].counts), timeout=WAIT_S)
        assert not os.path.exists(directory), f'{directory} was left behind'
    finally:
        launch.close()
        client.close()
        simulator.stop()


@pytest.mark.parametrize('ending', ['SIGTERM', 'Ctrl-C twice'])
def test_a_stopped_teleop_demo_leaves_nothing_running(install_prefix, tmp_path, ending):
    domain_id = next_domain_id()
    client = RosClient(domain_id, namespace='/right')
    launch = run_launch_file(install_prefix, domain_id, tmp_path / 'launch.log',
                             'teleop_demo.launch.py')
    try:
        client.wait(lambda: client.joint_states)
        directory = wait_for(lambda: SIM_DIRECTORY.search(launch.log()))[1]
        end(launch, ending)
        assert_every_process_ended_well(launch, ending)
        assert not os.path.exists(directory), f'{directory} was left behind'
    finally:
        launch.close()
        client.close()


def test_an_argument_the_file_does_not_take_stops_the_launch_before_any_process(
        install_prefix, tmp_path):
    # crtk is the driver's: given to teleop.launch.py, whose included driver took it, its CRTK
    # measured_cp came beside the simulated arm's and the bridge faulted (issue 43).
    launch = run_launch_file(install_prefix, next_domain_id(), tmp_path / 'launch.log',
                             'teleop.launch.py', right_port='sim', crtk='true')
    try:
        exits = launch.exits()
        log = launch.log()
        assert exits == {launch.pid: 1}, log
        assert started_processes(log) == {}, log
        (line,) = [line for line in log.splitlines() if '[ERROR]' in line]
        assert 'teleop.launch.py takes no argument crtk' in line
    finally:
        launch.close()


def enable_at_the_top(client, arm):
    """
    Enable the bridge of `arm` with the master's wrist at the top of the push, as the demo does.

    The bridge registers the master where it is when asked: there, each stroke brings the arm's
    hand down onto its table. A first call, `enable false`, opens the way for a prompt second.
    """
    from kraft_master_driver.tools.demo import ENGAGE_DISTANCE  # MuJoCo: only here
    top = kinematics.forward(Workspace().home(), arm)[:3, 3]
    enable = client.node.create_client(SetBool, 'enable')

    def call(data):
        assert enable.wait_for_service(timeout_sec=WAIT_S)
        future = enable.call_async(SetBool.Request(data=data))
        return client.wait(lambda: future.result())

    def at_the_top():
        position = client.poses and client.poses[-1].pose.position
        return position and np.linalg.norm(
            np.array([position.x, position.y, position.z]) - top) < ENGAGE_DISTANCE

    call(False)
    client.wait(lambda: at_the_top() and call(True).success)


@pytest.mark.parametrize('file_name, arguments, ending', [
    ('teleop.launch.py', {'right_port': 'sim'}, 'Ctrl-C'),
    ('teleop.launch.py', {'arms': 'both', 'right_port': 'sim', 'left_port': 'sim'}, 'SIGTERM'),
])
def test_the_panda_behind_the_bridge_is_felt_on_its_table_and_stops_with_the_launch(
        install_prefix, tmp_path, file_name, arguments, ending):
    domain_id = next_domain_id()
    arms = ('right', 'left') if arguments.get('arms') == 'both' else ('right',)
    clients = {arm: RosClient(domain_id, namespace=f'/{arm}') for arm in arms}
    table_forces = {arm: [] for arm in arms}
    for arm, client in clients.items():
        client.node.create_subscription(Vector3Stamped, 'table_force',
                                        table_forces[arm].append, 10)
    launch = run_launch_file(install_prefix, domain_id, tmp_path / 'launch.log', file_name,
                             arm_model='panda', sim_operator='push', enable='false',
                             **arguments)

    def felt(arm):
        # On the table, and the driver's torques show it.
        forces, states = table_forces[arm], clients[arm].joint_states
        return (forces and abs(forces[-1].vector.z) > 1.0
                and states and max(map(abs, states[-1].effort)) > 0.1)

    try:
        for arm, client in clients.items():
            enable_at_the_top(client, arm)
            client.wait(lambda: felt(arm))
            assert table_forces[arm][-1].header.frame_id == f'{arm}_sim_arm_base'
        assert sorted(name.rsplit('-', 1)[0] for name in started_processes(launch.log())
                      .values()) == sorted(['kraft_master_node', 'kraft_master_teleop',
                                            'kraft_master_arm_sim'] * len(arms))
        end(launch, ending)
        assert_every_process_ended_well(launch, ending)
    finally:
        launch.close()
        for client in clients.values():
            client.close()


def test_the_bridge_takes_param_set_while_following_and_stops_with_the_launch(
        install_prefix, tmp_path):
    # As `ros2 param set /right/kraft_master_teleop scale 2` does, under teleop.launch.py.
    domain_id = next_domain_id()
    client = RosClient(domain_id, namespace='/right')
    states = []
    client.node.create_subscription(String, 'operating_state', lambda m: states.append(m.data),
                                    QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                               durability=DurabilityPolicy.TRANSIENT_LOCAL))
    launch = run_launch_file(install_prefix, domain_id, tmp_path / 'launch.log',
                             'teleop.launch.py', right_port='sim', sim_operator='sweep')
    try:
        client.wait(lambda: states and states[-1] == 'ENABLED')
        parameters = AsyncParameterClient(client.node, '/right/kraft_master_teleop')
        assert parameters.wait_for_services(timeout_sec=WAIT_S)
        for name, value, reason in (('scale', 2.0, None), ('force_scale', 0.5, None),
                                    ('mode', 'twist', 'Trying to set a read-only parameter: '
                                     'mode.')):
            future = parameters.set_parameters([Parameter(name, value=value)])
            client.wait(future.done)
            (result,) = future.result().results
            assert (result.successful, result.reason or None) == (reason is None, reason)
        future = parameters.get_parameters(['scale', 'force_scale'])
        client.wait(future.done)
        assert [value.double_value for value in future.result().values] == [2.0, 0.5]
        assert states[-1] == 'ENABLED'
        end(launch, 'Ctrl-C')
        assert_every_process_ended_well(launch, 'Ctrl-C')
    finally:
        launch.close()
        client.close()
