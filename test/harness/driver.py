# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The installed driver and slave as processes, and a client node in the test process."""
import collections
import itertools
import os
import pathlib
import random
import select
import signal
import subprocess
import sys
import time

from geometry_msgs.msg import PoseStamped, WrenchStamped
from harness import dds_shm, PACKAGE, REPO
from kraft_master_driver.nodes.driver_parameters import PARAMETERS
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool


_domain_ids = itertools.count(random.Random(os.getpid()).randrange(20, 180, 10))
# Seconds a condition may take to come true: a start-up took over 20 s on a machine loaded
# about 15 times over its cores. Only a failing wait lasts this long.
WAIT_S = 120.0
# A command started as a shell at a terminal starts it, with SIGHUP at its default, also when the
# tests themselves run under nohup: a node keeps an inherited, ignored SIGHUP ignored.
AT_A_TERMINAL = ('env', '--default-signal=HUP')


def next_domain_id():
    """Return a ROS_DOMAIN_ID no other test of this run uses."""
    return next(_domain_ids) % 230 + 1


def wait_for(condition, timeout=WAIT_S, interval=0.01, spin=None):
    """Poll `condition` (spinning `spin` between polls) until it is truthy or time runs out."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if spin is not None:
            spin()
        value = condition()
        if value:
            return value
        time.sleep(0 if spin is not None else interval)
    raise AssertionError(f'condition not met within {timeout} s: {condition}')


def installed_env(prefix, domain_id):
    """Return the environment `source install/setup.bash` gives, on one DDS domain."""
    env = dict(os.environ)
    site = next((prefix / 'lib').glob('python3*/site-packages'))
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(site), env.get('PYTHONPATH')]))
    env['AMENT_PREFIX_PATH'] = os.pathsep.join(
        filter(None, [str(prefix), env.get('AMENT_PREFIX_PATH')]))
    env['ROS_DOMAIN_ID'] = str(domain_id)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['PYTHONUNBUFFERED'] = '1'
    # A node that dies of a signal (SIGSEGV, SIGABRT) prints every thread's stack first.
    env['PYTHONFAULTHANDLER'] = '1'
    return env


def colcon_build(workdir):
    """Build and install the package with colcon into `workdir`; return the install prefix."""
    colcon = pathlib.Path(sys.executable).parent / 'colcon'
    subprocess.run([str(colcon), '--log-base', str(workdir / 'log'), 'build', '--base-paths',
                    str(REPO), '--build-base', str(workdir / 'build'), '--install-base',
                    str(workdir / 'install')], cwd=workdir, check=True,
                   stdout=subprocess.DEVNULL)
    return workdir / 'install' / PACKAGE


def executable(prefix, name):
    """Path of an installed executable where `ros2 run kraft_master_driver <name>` looks."""
    path = prefix / 'lib' / PACKAGE / name
    assert os.access(path, os.X_OK), f'{path} is not an installed executable'
    return path


class ClientNode:
    """A node of the test's process, with a context and an executor of its own."""

    def __init__(self, domain_id, name, namespace='/'):
        """Join DDS domain `domain_id` as node `name` in `namespace`."""
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node(name, namespace=namespace, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin(self, seconds=0.0):
        """Process callbacks for about `seconds` (at least once)."""
        deadline = time.monotonic() + seconds
        self.executor.spin_once(timeout_sec=0.01)
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)

    def close(self):
        """Leave the domain."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


class RosClient(ClientNode):
    """Subscribes to one driver's state, publishes wrenches, calls its services."""

    def __init__(self, domain_id, namespace='/', history=2000):
        """Join DDS domain `domain_id` and listen to the driver in `namespace`."""
        super().__init__(domain_id, 'test_client', namespace)
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.joint_states, self.poses, self.pots = (
            self._record(msg_type, topic, history, reliable)
            for msg_type, topic in ((JointState, 'joint_states'), (PoseStamped, 'pose'),
                                    (JointState, 'pots')))
        self._wrench_pub = None
        self.enable_client = self.node.create_client(SetBool, 'enable_force')

    @property
    def wrench_pub(self):
        """Return the wrench publisher, made on first use: the driver accepts one source."""
        if self._wrench_pub is None:
            self._wrench_pub = self.node.create_publisher(
                WrenchStamped, 'wrench',
                QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        return self._wrench_pub

    def _record(self, msg_type, topic, history, qos):
        messages = collections.deque(maxlen=history)
        self.node.create_subscription(msg_type, topic, lambda msg: messages.append(msg), qos)
        return messages

    def wait(self, condition, timeout=WAIT_S):
        """Spin until `condition()` is truthy."""
        return wait_for(condition, timeout, spin=self.spin)

    def wait_connected(self):
        """Wait until the driver publishes state and listens to our wrenches."""
        self.wait(lambda: self.joint_states and self.wrench_pub.get_subscription_count() > 0)

    def publish_wrench(self, wrench, frame_id):
        """Publish one WrenchStamped stamped now."""
        msg = WrenchStamped()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.header.frame_id = frame_id
        f, m = msg.wrench.force, msg.wrench.torque
        f.x, f.y, f.z, m.x, m.y, m.z = (float(v) for v in wrench)
        self.wrench_pub.publish(msg)

    def stream_wrench(self, wrench, frame_id, seconds, period=0.005):
        """Publish the wrench every `period` s for `seconds`, spinning in between."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.publish_wrench(wrench, frame_id)
            self.spin(period)

    def stream_wrench_until(self, wrench, frame_id, condition, timeout=WAIT_S):
        """Publish the wrench every few ms until `condition()` holds."""
        def publish_and_check():
            self.publish_wrench(wrench, frame_id)
            return condition()
        return wait_for(publish_and_check, timeout, spin=lambda: self.spin(0.003))

    def set_force_enabled(self, enabled):
        """Call enable_force and return the response."""
        assert self.enable_client.wait_for_service(timeout_sec=WAIT_S)
        future = self.enable_client.call_async(SetBool.Request(data=enabled))
        self.wait(future.done)
        return future.result()


class DriverProcess:
    """An installed executable of the package, started as `ros2 run` would start it."""

    def __init__(self, prefix, domain_id, parameters=(), namespace=None, params_file=None,
                 name='kraft_master_node', wrapper=()):
        """Start `wrapper` + executable `name` with `-p name:=value` for each of `parameters`."""
        command = [*AT_A_TERMINAL, *wrapper, str(executable(prefix, name)), '--ros-args']
        if namespace:
            command += ['-r', f'__ns:={namespace}']
        if params_file:
            command += ['--params-file', str(params_file)]
        for parameter, value in parameters:
            command += ['-p', f'{parameter}:={value}']
        self.process = subprocess.Popen(
            command, env=installed_env(prefix, domain_id), stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True)
        self.read = ''  # the output read_until() took

    def read_until(self, text, timeout=WAIT_S):
        """Read the output until it holds `text`; the exit's output keeps what was read."""
        fd = self.process.stdout.fileno()  # read raw: the pipe's text reader stays empty
        deadline = time.monotonic() + timeout
        taken = self.read.encode()
        while text not in self.read:
            remaining = deadline - time.monotonic()
            assert remaining > 0 and select.select([fd], [], [], remaining)[0], \
                f'no {text!r} within {timeout} s: {self.read[-2000:]}'
            chunk = os.read(fd, 65536)
            assert chunk, f'the output ended without {text!r}: {self.read[-2000:]}'
            taken += chunk
            self.read = taken.decode(errors='replace')

    def interrupt(self, sig=signal.SIGINT, timeout=WAIT_S):
        """Send `sig`, wait for the exit; return (exit code, output)."""
        self.process.send_signal(sig)
        output, _ = self.process.communicate(timeout=timeout)
        return self.process.returncode, self.read + output

    def wait_exit(self, timeout=WAIT_S):
        """Wait for the process to end by itself; return (exit code, output)."""
        output, _ = self.process.communicate(timeout=timeout)
        return self.process.returncode, output

    def kill(self):
        """Make sure the process is gone: SIGTERM (DDS tears down), SIGKILL if that fails."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.communicate(timeout=WAIT_S)
            except subprocess.TimeoutExpired:
                dds_shm.kill_and_clean(self.process)
                self.process.communicate(timeout=10)


class DriverSession:
    """A simulated device in this process, the driver process on its pty, a client node."""

    def __init__(self, prefix, parameters=(), namespace=None, arm='right', domain_id=None,
                 wrapper=(), params_file=None, simulator_options=None):
        """Start all three; the client listens in the driver's namespace."""
        self.domain_id = domain_id or next_domain_id()
        # The device stands in for hardware, which answers whatever the machine's load: its
        # thread at the driver loop's real-time priority. Starved for over 100 ms, it runs its
        # command watchdog before it reads the commands waiting, and zeroes the torques.
        self.simulator = SimulatedKraftMaster(arm=arm, operator='hold', **{
            'priority': PARAMETERS['loop_priority'].default, **(simulator_options or {})})
        self.port = port = self.simulator.start()
        parameters = [('port', port), ('arm', arm), *parameters]
        self.driver = DriverProcess(prefix, self.domain_id, parameters, namespace=namespace,
                                    wrapper=wrapper, params_file=params_file)
        self.client = RosClient(self.domain_id, namespace=namespace or '/')
        try:
            self.client.wait_connected()
        except AssertionError:
            self.close()
            raise AssertionError('driver did not connect:\n' + self.driver.wait_exit()[1])

    def last_command(self):
        """Return the torque counts of the newest command the device received."""
        return self.simulator.received[-1][1].counts

    def close(self):
        """Stop everything, whatever state the test left it in."""
        self.client.close()
        self.driver.kill()
        self.simulator.stop()


def slave_process(prefix, domain_id, parameters=()):
    """Start the installed kraft_master_slave_sim with `-p name:=value` parameters."""
    return DriverProcess(prefix, domain_id, parameters, name='kraft_master_slave_sim')


def vector_parameter(values):
    """Format a float array for `-p name:=[...]`."""
    return '[' + ', '.join(f'{float(v)!r}' for v in values) + ']'
