# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
`make demo` as a user runs it: the demo module with its own processes, its output piped.

A recorder on the demo's DDS domain keeps every message the driver, the bridge and the
simulated arm publish, so that the contact and the reflected force are checked in the messages
themselves as well as in what the demo prints. The demo runs in a session of its own: once it
has exited, no process of that session may be left.
"""
import os
import re
import signal
import subprocess
import sys
import threading

from geometry_msgs.msg import PoseStamped, WrenchStamped
from harness import dds_shm, REPO
from harness.driver import next_domain_id, wait_for
from kraft_master_driver.core import kinematics
from kraft_master_driver.nodes.driver_parameters import PARAMETERS as DRIVER_PARAMETERS
from kraft_master_driver.tools.demo import WALL_Z
import numpy as np
import pytest
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

pytestmark = pytest.mark.integration

DURATION = 12.0  # s of teleoperation: three strokes of the simulated operator's push
FORCE_SCALE = DRIVER_PARAMETERS['force_scale'].default
TORQUE_RESOLUTION = 1.5e-3  # N*m: the device's 1 mN*m counts, on th2 the sum of two
PAIRING_WINDOW = 0.1  # s: a torque matches a wrench stamped this close to its state


class Recorder:
    """Takes every message of the demo's topics from deep queues, without an executor."""

    TOPICS = (('joint_states', JointState), ('wrench', WrenchStamped),
              ('measured_cp', PoseStamped))

    def __init__(self, domain_id):
        """Subscribe on `domain_id` and start taking in a thread."""
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node('demo_recorder', context=self.context)
        qos = QoSProfile(depth=5000, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.raw = {topic: [] for topic, _ in self.TOPICS}
        self._subscriptions = [
            (topic, msg_type, self.node.create_subscription(
                msg_type, topic, lambda _msg: None, qos, raw=True))
            for topic, msg_type in self.TOPICS]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._take_until_stopped)
        self._thread.start()

    def _take_until_stopped(self):
        while not self._stop.wait(0.05):
            for topic, msg_type, subscription in self._subscriptions:
                with subscription.handle:
                    while (taken := subscription.handle.take_message(msg_type, True)) is not None:
                        self.raw[topic].append(taken[0])

    def messages(self, topic):
        """Return the messages taken on `topic`, oldest first."""
        msg_type = dict(self.TOPICS)[topic]
        return [deserialize_message(data, msg_type) for data in self.raw[topic]]

    def close(self):
        """Stop taking and leave the domain."""
        self._stop.set()
        self._thread.join()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def session_processes(session_id):
    """Return the ids of the processes in session `session_id`."""
    found = []
    for entry in filter(str.isdigit, os.listdir('/proc')):
        try:
            with open(f'/proc/{entry}/stat') as stat:
                fields = stat.read().rpartition(')')[2].split()
        except (FileNotFoundError, ProcessLookupError):  # it ended meanwhile
            continue
        if int(fields[3]) == session_id:
            found.append(int(entry))
    return found


class Demo:
    """The demo module run as `make demo` runs it, on a DDS domain of its own, output piped."""

    def __init__(self, duration, sigint_ignored=False):
        """Start recording, then the demo (`sigint_ignored`: as a background job); read it."""
        domain_id = next_domain_id()
        self.recorder = Recorder(domain_id)
        # PYTHONFAULTHANDLER: a demo that hangs shows its threads' stacks on SIGABRT.
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONFAULTHANDLER='1')
        command = [sys.executable, '-m', 'kraft_master_driver.tools.demo',
                   '--duration', str(duration)]
        if sigint_ignored:
            command = ['sh', '-c', 'trap "" INT; exec "$@"', 'sh', *command]
        self.process = subprocess.Popen(
            command, cwd=REPO, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True, start_new_session=True)
        self.lines = []
        self._reader = threading.Thread(target=lambda: self.lines.extend(self.process.stdout))
        self._reader.start()

    def finish(self, timeout=180.0):
        """Wait for the demo to exit; return (exit code, output); fail with both if it hangs."""
        try:
            code = self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.process.send_signal(signal.SIGABRT)
            code = self.process.wait(30.0)
            hung = True
        else:
            hung = False
        finally:
            self._reader.join(timeout=30.0)
            self.recorder.close()
        output = ''.join(self.lines)
        assert not hung, f'the demo did not exit within {timeout:g} s; its output:\n{output}'
        return code, output

    def kill(self):
        """Make sure the demo and everything in its session are gone: SIGTERM, then SIGKILL."""
        for pid in session_processes(self.process.pid):
            try:
                os.kill(pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        try:
            wait_for(lambda: self.process.poll() is not None and not session_processes(
                self.process.pid), timeout=60.0)
        except AssertionError:
            for pid in session_processes(self.process.pid):
                held = dds_shm.held_by(pid)
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                dds_shm.remove(dds_shm.orphaned(held))
        if self.process.poll() is None:
            self.process.wait()


@pytest.fixture
def start_demo():
    """Yield start(duration) -> Demo; whatever happens, nothing of it is left."""
    started = []

    def start(duration, **options):
        started.append(Demo(duration, **options))
        return started[-1]

    yield start
    for demo in started:
        demo.kill()
        if demo.recorder.context.ok():
            demo.recorder.close()


def implied_force(jacobian, effort):
    """Return the pure force F (3,) with effort = J^T (F, 0) on th1..th5 (least squares)."""
    return np.linalg.lstsq(jacobian[:3, :5].T, np.asarray(effort)[:5], rcond=None)[0]


def seconds(stamp):
    """Return a header stamp in seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


def readouts(output):
    """Return the piped readouts: (seconds, {line label: numbers}) each."""
    blocks = []
    for block in re.split(r'\n\n', output):
        match = re.match(r' *([0-9.]+) s \| loop', block)
        if match:
            rows = {label: [float(v) for v in re.findall(r'-?\d+\.\d+', numbers)]
                    for label, _, numbers in (line.partition('  ')
                                              for line in block.splitlines()[1:])}
            blocks.append((float(match.group(1)), rows))
    return blocks


def test_the_demo_shows_contact_and_reflected_force_and_leaves_nothing(start_demo):
    demo = start_demo(DURATION)
    code, output = demo.finish()
    assert code == 0, output
    assert not session_processes(demo.process.pid), 'a process of the demo was left behind'

    # The processes' messages are in the log file and were shown above the readouts.
    log_path = re.search(r"The processes' messages go to (\S+), and are shown here", output)[1]
    with open(log_path) as log_file:
        log = log_file.read()
    os.remove(log_path)
    assert 'right Kraft Master on' in log and 'simulated arm in pose mode' in log
    assert 'enable True: ENABLED' in log
    for line in log.splitlines():
        assert line in output
    assert output.rstrip().endswith(f"The processes' messages: {log_path}")

    # What the demo showed: the arm at the wall and the force on the master, within 10 s.
    shown = readouts(output)
    assert shown and shown[-1][0] >= DURATION
    touching = [t for t, rows in shown if rows['arm (mm)'][2] <= 1e3 * WALL_Z
                and rows['wrench on master (N)'][2] > 1.0 and any(rows['torques (N*m)'])]
    assert touching and touching[0] <= 10.0, output

    # What was published: the arm stopped at the wall, which pushed back along +z.
    arm_z = np.array([p.pose.position.z for p in demo.recorder.messages('measured_cp')])
    assert WALL_Z - 0.003 < arm_z.min() < WALL_Z
    forces = np.array([(w.wrench.force.x, w.wrench.force.y, w.wrench.force.z)
                       for w in demo.recorder.messages('wrench')])
    assert forces[:, 2].min() >= 0.0 and forces[:, 2].max() > 1.0
    np.testing.assert_array_equal(forces[:, :2], 0.0)

    # The master's torques are J^T (force_scale F) of that force, with the Jacobian of the
    # state before (the one the driver used), so they push the wrist up, out of the wall.
    # Only torques whose wrenches the recorder can have seen are paired: DDS sometimes matches
    # a late joiner's endpoints one announcement period (about 3 s) after the driver's, and
    # what the bridge sent before then never reached the recorder.
    states = demo.recorder.messages('joint_states')
    wrench_times = np.array([seconds(w.header.stamp) for w in demo.recorder.messages('wrench')])
    recorded_from = wrench_times.min() + PAIRING_WINDOW
    checked = matched = 0
    for previous, state in zip(states, states[1:]):
        if (np.abs(state.effort).max() < 20 * TORQUE_RESOLUTION
                or seconds(state.header.stamp) < recorded_from):
            continue
        force = implied_force(kinematics.jacobian(previous.position), state.effort) / FORCE_SCALE
        assert force[2] > 0.0, 'the torques must push the wrist up, out of the wall'
        assert np.linalg.norm(force[:2]) < 0.05 * force[2] + 0.02
        recent = forces[np.abs(wrench_times - seconds(state.header.stamp)) < PAIRING_WINDOW, 2]
        checked += 1
        if recent.size and np.abs(recent - force[2]).min() < 0.02 * force[2] + 0.02:
            matched += 1
    assert checked >= 100
    assert matched >= 0.95 * checked, f'{matched} of {checked} torques match a wrench sent'


# The demo started from a shell's background job comes with SIGINT ignored; Ctrl-C or a kill -INT
# must stop it all the same.
@pytest.mark.parametrize('sig, sigint_ignored', [(signal.SIGINT, False), (signal.SIGINT, True),
                                                 (signal.SIGTERM, False), (signal.SIGHUP, False)])
def test_a_signal_to_the_demo_stops_every_process(start_demo, sig, sigint_ignored):
    demo = start_demo(600.0, sigint_ignored=sigint_ignored)
    wait_for(lambda: any(' s | loop ' in line for line in demo.lines), timeout=120.0)
    demo.process.send_signal(sig)
    code, output = demo.finish(timeout=60.0)
    assert code == 0, output
    assert not session_processes(demo.process.pid), 'a process of the demo was left behind'
    assert "The processes' messages: " in output.splitlines()[-1]
