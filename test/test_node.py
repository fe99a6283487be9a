# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The installed kraft_master_node against a simulated device on a real pseudo-terminal."""
import math
import os
import pathlib
import signal
import time

from driver_harness import DriverProcess, next_domain_id, RosClient, wait_for
from kraft_master_driver import kinematics
from kraft_master_driver.calibration import ArmCalibration
from kraft_master_driver.protocol import DEFAULT_TORQUE_SCALE
from kraft_master_driver.simulator import SimulatedKraftMaster
import numpy as np
import pytest

pytestmark = pytest.mark.integration

BASE, WRIST = 'kraft_master_base', 'kraft_master_wrist'
WRENCH = (3.0, -2.0, 4.0, 0.05, -0.1, 0.08)


class Session:
    """A simulated device in this process, the driver process on its pty, a client node."""

    def __init__(self, prefix, parameters=(), namespace=None, arm='right', domain_id=None,
                 wrapper=()):
        """Start all three; the client listens in the driver's namespace."""
        self.domain_id = domain_id or next_domain_id()
        self.simulator = SimulatedKraftMaster(arm=arm, operator='hold')
        port = self.simulator.start()
        parameters = [('port', port), ('arm', arm), *parameters]
        self.driver = DriverProcess(prefix, self.domain_id, parameters, namespace=namespace,
                                    wrapper=wrapper)
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


@pytest.fixture
def session(install_prefix):
    """Yield a running driver with force output enabled at start-up."""
    running = Session(install_prefix, [('force_enabled_at_start', 'true')])
    yield running
    running.close()


def expected_effort(position, wrench, arm='right'):
    """Joint torques J^T F at `position`, th6 not driven."""
    tau = kinematics.jacobian(position, arm).T @ np.asarray(wrench)
    tau[5] = 0.0
    return tau


def stream_until_torque(client, frame_id=BASE):
    """Publish WRENCH until the driver reports torque (discovery takes a while)."""
    client.stream_wrench_until(WRENCH, frame_id, lambda: any(client.joint_states[-1].effort))


@pytest.mark.parametrize('rate_hz', [100.0, 250.0])
def test_joint_states_arrive_at_the_configured_rate(install_prefix, rate_hz):
    """A Python test client cannot follow 1 kHz; benchmarks/loop.py measures that rate."""
    running = Session(install_prefix, [('loop_rate_hz', rate_hz)])
    try:
        client, simulator = running.client, running.simulator
        client.spin(0.5)
        commands, started = simulator.stats['commands'], time.monotonic()
        client.spin(2.0)
        device_rate = (simulator.stats['commands'] - commands) / (time.monotonic() - started)
        # Paced, not free-running; a loaded machine may only slow it (figures: benchmarks).
        assert 0.5 * rate_hz < device_rate < 1.05 * rate_hz
        stamps = [s.header.stamp.sec + s.header.stamp.nanosec * 1e-9
                  for s in client.joint_states]
        assert np.median(np.diff(stamps)) == pytest.approx(1.0 / rate_hz, rel=0.25)
        message = client.joint_states[-1]
        assert list(message.name) == list(kinematics.JOINT_NAMES)
        assert message.header.frame_id == BASE
    finally:
        running.close()


def test_pose_is_forward_kinematics_of_the_same_sample(session):
    client = session.client
    client.wait(lambda: len(client.poses) > 50)
    poses = {(p.header.stamp.sec, p.header.stamp.nanosec): p.pose for p in client.poses}
    matched = 0
    for state in list(client.joint_states):
        pose = poses.get((state.header.stamp.sec, state.header.stamp.nanosec))
        if pose is None:
            continue
        matched += 1
        transform = kinematics.forward(state.position)
        position = [pose.position.x, pose.position.y, pose.position.z]
        np.testing.assert_allclose(position, transform[:3, 3], atol=1e-9)
        q = pose.orientation
        expected = kinematics.rotation_to_quaternion(transform)
        np.testing.assert_allclose([q.x, q.y, q.z, q.w], expected, atol=1e-9)
    assert matched > 20


def test_pots_are_the_raw_counts_of_the_same_sample(session):
    client = session.client
    client.wait(lambda: len(client.pots) > 50)
    calibration = ArmCalibration.nominal('right')
    states = {(s.header.stamp.sec, s.header.stamp.nanosec): s for s in client.joint_states}
    pots = [p for p in client.pots if (p.header.stamp.sec, p.header.stamp.nanosec) in states]
    assert pots
    for message in pots:
        state = states[(message.header.stamp.sec, message.header.stamp.nanosec)]
        assert all(float(c).is_integer() and 0 <= c <= 4095 for c in message.position)
        np.testing.assert_allclose(
            calibration.pots_to_joints(message.position), state.position, atol=1e-12)


def latest_with_torque(client):
    """Return the newest joint state that carries a commanded torque."""
    return next(s for s in reversed(client.joint_states) if any(s.effort))


def test_wrench_gives_effort_j_transpose_f_and_device_counts(session):
    client = session.client
    stream_until_torque(client)
    state = latest_with_torque(client)
    effort = np.array(state.effort)
    np.testing.assert_allclose(effort, expected_effort(state.position, WRENCH), atol=2e-3)
    expected_counts = np.round(kinematics.actuator_torques(effort)[:5] * DEFAULT_TORQUE_SCALE)
    recent = np.array([command.counts for _, command in list(session.simulator.received)[-50:]])
    assert np.abs(expected_counts).max() > 50
    assert np.any(np.all(np.abs(recent - expected_counts) <= 3, axis=1)), recent[-5:]


def test_wrist_frame_wrench_is_rotated_into_the_base_frame(session):
    client = session.client
    stream_until_torque(client, frame_id=WRIST)
    state = latest_with_torque(client)
    rotation = kinematics.forward(state.position)[:3, :3]
    base_wrench = np.concatenate([rotation @ WRENCH[:3], rotation @ WRENCH[3:]])
    np.testing.assert_allclose(
        state.effort, expected_effort(state.position, base_wrench), atol=2e-3)


def wait_zero_torque(session):
    client = session.client
    client.wait(lambda: not any(client.joint_states[-1].effort) and
                not any(session.last_command()))


def test_watchdog_zeroes_torque_when_wrenches_stop(session):
    client = session.client
    stream_until_torque(client)
    client.spin(0.2)
    wait_zero_torque(session)


@pytest.mark.parametrize('wrench, frame_id', [
    ((math.nan, 0, 0, 0, 0, 0), BASE),
    ((math.inf, 0, 0, 0, 0, 0), BASE),
    ((1e9, 0, 0, 0, 0, 0), BASE),
    (WRENCH, 'some_other_frame'),
    (WRENCH, ''),
])
def test_rejected_wrench_zeroes_torque(session, wrench, frame_id):
    client = session.client
    stream_until_torque(client)
    client.publish_wrench(wrench, frame_id)
    client.stream_wrench(wrench, frame_id, seconds=0.2)
    wait_zero_torque(session)


def test_disable_and_enable_force_output(session):
    client = session.client
    assert client.set_force_enabled(False).success
    client.stream_wrench(WRENCH, BASE, seconds=0.5)
    wait_zero_torque(session)
    assert client.set_force_enabled(True).success
    stream_until_torque(client)


def test_force_output_is_off_by_default(install_prefix):
    running = Session(install_prefix)
    try:
        running.client.stream_wrench(WRENCH, BASE, seconds=0.5)
        assert running.client.joint_states
        assert not any(running.client.joint_states[-1].effort)
        assert not any(running.last_command())
    finally:
        running.close()


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_signal_writes_zero_torque_then_exits_0(install_prefix, sig):
    running = Session(install_prefix, [('force_enabled_at_start', 'true')])
    try:
        client = running.client
        client.stream_wrench_until(WRENCH, BASE, lambda: any(running.last_command()))
        code, output = running.driver.interrupt(sig)
        assert code == 0, output
        # The driver has exited; the simulator may still be reading its last bytes.
        assert wait_for(lambda: not any(running.last_command()), timeout=5.0), \
            'the last command must be zero torque'
    finally:
        running.close()


def scheduling_of_threads(pid):
    """Return (policy, rt_priority) of each thread of process pid (Linux /proc)."""
    result = []
    for stat in pathlib.Path(f'/proc/{pid}/task').glob('*/stat'):
        fields = stat.read_text().rsplit(')', 1)[1].split()
        result.append((int(fields[38]), int(fields[37])))  # stat fields 41 and 40
    return result


def test_loop_thread_runs_at_the_real_time_priority_asked(install_prefix):
    running = Session(install_prefix, [('loop_priority', '30')])
    try:
        assert running.client.joint_states
        threads = scheduling_of_threads(running.driver.process.pid)
        assert threads.count((os.SCHED_FIFO, 30)) == 1, threads
        assert sum(policy != os.SCHED_OTHER for policy, _ in threads) == 1, threads
    finally:
        running.close()


def test_refused_real_time_priority_warns_and_runs_at_normal_priority(install_prefix):
    without_sys_nice = ['setpriv', '--inh-caps', '-sys_nice', '--bounding-set', '-sys_nice']
    running = Session(install_prefix, [('loop_priority', '30')], wrapper=without_sys_nice)
    try:
        count = len(running.client.joint_states)
        running.client.wait(lambda: len(running.client.joint_states) > count + 100)
        threads = scheduling_of_threads(running.driver.process.pid)
        assert all(policy == os.SCHED_OTHER for policy, _ in threads), threads
        code, output = running.driver.interrupt()
        assert code == 0, output
        assert 'loop_priority 30: real-time scheduling refused' in output
    finally:
        running.close()


@pytest.mark.parametrize('name, value, fragment', [
    ('loop_rate_hz', '0.0', 'loop_rate_hz'),
    ('arm', 'middle', 'arm'),
    ('torque_limits', '[1.0, 2.0]', 'torque_limits'),
    ('baud', 'fast', 'baud'),
    ('calibration.pot_a', '[157.0, 751.0, 248.0, 1126.0, 500.0, 99999.0]', 'calibration.pot_a'),
    ('calibration.pot_b', '[157.0, 3328.0, 3863.0, 2766.0, 2930.0, 2656.0]',
     'a calibration must give all of'),
])
def test_bad_parameter_exits_1_naming_it(install_prefix, name, value, fragment):
    driver = DriverProcess(install_prefix, next_domain_id(), [(name, value)])
    code, output = driver.wait_exit()
    assert code == 1, output
    assert fragment in output


def test_bad_calibration_file_exits_1_naming_it(install_prefix, tmp_path):
    params = tmp_path / 'bad_arm.yaml'
    params.write_text('/**:\n  ros__parameters:\n    calibration:\n'
                      '      pot_a: [1.0, 2.0, 3.0]\n')
    driver = DriverProcess(install_prefix, next_domain_id(), params_file=params)
    code, output = driver.wait_exit()
    assert code == 1, output
    assert 'calibration.pot_a' in output


def test_two_arms_side_by_side(install_prefix):
    domain_id = next_domain_id()
    left = Session(install_prefix, [('joint_prefix', 'left_')], namespace='/left',
                   arm='left', domain_id=domain_id)
    right = Session(install_prefix, [('joint_prefix', 'right_')], namespace='/right',
                    domain_id=domain_id)
    try:
        for running, arm in ((left, 'left'), (right, 'right')):
            running.client.spin(0.5)
            state = running.client.joint_states[-1]
            assert state.name[0] == f'{arm}_shoulder_yaw'
            pose = running.client.poses[-1].pose.position
            expected = kinematics.forward(state.position, arm)[:3, 3]
            np.testing.assert_allclose([pose.x, pose.y, pose.z], expected, atol=1e-3)
        left_y = left.client.poses[-1].pose.position.y
        right_y = right.client.poses[-1].pose.position.y
        assert left_y != pytest.approx(right_y, abs=1e-3), 'the arms mirror L3'
    finally:
        left.close()
        right.close()
