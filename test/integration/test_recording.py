# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""A live session of the installed driver recorded into rosbag2 (mcap, sqlite3) and read back."""
import collections
import csv
import re
import signal
import sqlite3
import subprocess
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, WrenchStamped
from harness import dds_shm
from harness.driver import (ClientNode, DriverProcess, executable, installed_env, next_domain_id,
                            wait_for)
from harness.type_hashes import generated_type_hash
from kraft_master_driver.bag.common import (
    DIAGNOSTIC_ARRAY, DRIVER_TOPICS, JOINT_STATE, POSE_STAMPED, typestore)
from kraft_master_driver.bag.reader import read_topics
from kraft_master_driver.bag.recorder import BagRecorder, qos_profile, STORAGES
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
from kraft_master_driver.tools import record, report
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.topic_endpoint_info import TopicEndpointInfo
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import JointState

pytestmark = pytest.mark.integration

TOPICS = {'/joint_states': JointState, '/pose': PoseStamped, '/pots': JointState,
          '/diagnostics': DiagnosticArray, '/wrench': WrenchStamped}
WRENCH = (4.0, -3.0, 5.0, 0.1, -0.1, 0.05)
RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


def type_name(msg_type):
    """Return the ROS 2 type name of an rclpy message class, e.g. sensor_msgs/msg/JointState."""
    return f'{msg_type.__module__.split(".")[0]}/msg/{msg_type.__name__}'


def offered_qos(info):
    """Return the QoS profile a publisher offers, as ros2 bag stores it."""
    qos = info.qos_profile
    return qos_profile(
        reliability=qos.reliability.name, durability=qos.durability.name,
        history=qos.history.name, depth=qos.depth, deadline_ns=qos.deadline.nanoseconds,
        lifespan_ns=qos.lifespan.nanoseconds, liveliness=qos.liveliness.name,
        liveliness_lease_duration_ns=qos.liveliness_lease_duration.nanoseconds,
        avoid_ros_namespace_conventions=qos.avoid_ros_namespace_conventions)


class LiveRecorder(ClientNode):
    """A node in this process that records raw messages into one bag per storage plugin."""

    def __init__(self, domain_id, directory):
        """Join the domain; nothing is recorded until start()."""
        super().__init__(domain_id, 'session_recorder')
        self.wrench_pub = self.node.create_publisher(WrenchStamped, '/wrench', RELIABLE)
        self.bags = {storage: directory / storage for storage in STORAGES}
        self.recorders = [BagRecorder(path, storage)
                          for storage, path in self.bags.items()]
        self.received = {topic: [] for topic in TOPICS}
        self.offered = {}

    def start(self):
        """Wait for the driver's publishers, then subscribe to every topic, raw."""
        wait_for(lambda: all(self.node.count_publishers(topic) for topic in TOPICS) and
                 self.wrench_pub.get_subscription_count() > 0, timeout=120.0,
                 spin=lambda: self.spin(0.05))
        for topic, msg_type in TOPICS.items():
            self.offered[topic] = [offered_qos(info) for info
                                   in self.node.get_publishers_info_by_topic(topic)]
            for recorder in self.recorders:
                recorder.add_topic(topic, type_name(msg_type), self.offered[topic])
            self.node.create_subscription(msg_type, topic, self._recorder(topic), RELIABLE,
                                          raw=True)

    def _recorder(self, topic):
        def record(data):
            received_ns = time.time_ns()
            self.received[topic].append((received_ns, data))
            for recorder in self.recorders:
                recorder.write(topic, received_ns, data)
        return record

    def publish_wrench(self):
        """Publish WRENCH in the base frame, stamped now."""
        message = WrenchStamped()
        message.header.stamp = self.node.get_clock().now().to_msg()
        message.header.frame_id = 'kraft_master_base'
        force, torque = message.wrench.force, message.wrench.torque
        force.x, force.y, force.z, torque.x, torque.y, torque.z = WRENCH
        self.wrench_pub.publish(message)

    def close(self):
        """Close the bags and leave the domain."""
        for recorder in self.recorders:
            recorder.close()
        super().close()


@pytest.fixture(scope='module')
def recorded(install_prefix, tmp_path_factory):
    """Record a few seconds of a moving arm under a task wrench; return the LiveRecorder."""
    domain_id = next_domain_id()
    simulator = SimulatedKraftMaster(arm='right', operator='sweep', operator_period=1.0,
                                     pot_noise_counts=1.0)
    port = simulator.start()
    driver = DriverProcess(install_prefix, domain_id, [
        ('port', port), ('arm', 'right'), ('loop_rate_hz', 200.0),
        ('force_enabled_at_start', 'true')])
    recorder = LiveRecorder(domain_id, tmp_path_factory.mktemp('bags'))
    try:
        recorder.start()

        def publish_and_check():
            recorder.publish_wrench()
            recorder.spin(0.005)
            states = recorder.received['/joint_states']
            return len(recorder.received['/diagnostics']) >= 2 and len(states) >= 400
        wait_for(publish_and_check, timeout=120.0)
    finally:
        recorder.close()
        driver.kill()
        simulator.stop()
    return recorder


@pytest.mark.parametrize('storage', sorted(STORAGES))
def test_bag_holds_what_was_received(recorded, storage):
    store = typestore()
    with Reader(recorded.bags[storage]) as reader:
        connections = {c.topic: c for c in reader.connections}
        assert set(connections) == set(TOPICS)
        in_bag = {topic: [] for topic in TOPICS}
        for connection, log_time, data in reader.messages():
            in_bag[connection.topic].append((log_time, bytes(data)))
    for topic, msg_type in TOPICS.items():
        connection = connections[topic]
        assert connection.msgtype == type_name(msg_type)
        assert connection.ext.offered_qos_profiles == recorded.offered[topic]
        assert connection.msgcount == len(recorded.received[topic])
        assert in_bag[topic] == [(t, bytes(d)) for t, d in recorded.received[topic]]
    # Driver topics: reliable, volatile, as the driver offers them.
    (qos,) = recorded.offered['/joint_states']
    assert qos.reliability.name == 'RELIABLE' and qos.durability.name == 'VOLATILE'

    states = [store.deserialize_cdr(d, connections['/joint_states'].msgtype)
              for _, d in in_bag['/joint_states']]
    pots = {(m.header.stamp.sec, m.header.stamp.nanosec): m.position for m in (
        store.deserialize_cdr(d, JOINT_STATE) for _, d in in_bag['/pots'])}
    assert all(list(s.name) == list(kinematics.JOINT_NAMES) for s in states)
    nominal = ArmCalibration.nominal('right')
    matched = [(s.position, pots[(s.header.stamp.sec, s.header.stamp.nanosec)])
               for s in states if (s.header.stamp.sec, s.header.stamp.nanosec) in pots]
    assert len(matched) > 300
    for position, counts in matched:
        np.testing.assert_allclose(position, nominal.pots_to_joints(counts), atol=1e-12)
    positions = np.array([s.position for s in states])
    assert np.ptp(positions, axis=0).max() > np.radians(10.0), 'the sweeping hand moves the arm'
    assert any(np.abs(s.effort).max() > 0.01 for s in states), 'the wrench gives torques'
    diagnostics = store.deserialize_cdr(in_bag['/diagnostics'][-1][1], DIAGNOSTIC_ARRAY)
    assert any(v.key == 'link timeouts' for v in diagnostics.status[0].values)


@pytest.mark.parametrize('storage', sorted(STORAGES))
def test_fast_reader_equals_rosbags_on_the_recording(recorded, storage):
    store = typestore()
    data = read_topics(recorded.bags[storage], TOPICS)
    for topic, msg_type in TOPICS.items():
        received = recorded.received[topic]
        np.testing.assert_array_equal(data[topic].log_time, [t for t, _ in received])
        messages = [store.deserialize_cdr(bytes(d), type_name(msg_type)) for _, d in received]
        if topic == '/diagnostics':
            assert data[topic].messages == messages
            continue
        stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in messages]
        np.testing.assert_array_equal(data[topic].fields['stamp'], stamps)
    states = [store.deserialize_cdr(bytes(d), JOINT_STATE)
              for _, d in recorded.received['/joint_states']]
    for field in ('position', 'velocity', 'effort'):
        np.testing.assert_array_equal(data['/joint_states'].fields[field],
                                      [getattr(s, field) for s in states])
    poses = [store.deserialize_cdr(bytes(d), POSE_STAMPED).pose
             for _, d in recorded.received['/pose']]
    np.testing.assert_array_equal(data['/pose'].fields['orientation'],
                                  [[p.orientation.x, p.orientation.y, p.orientation.z,
                                    p.orientation.w] for p in poses])
    wrench = data['/wrench'].fields
    np.testing.assert_array_equal(wrench['force'][-1], WRENCH[:3])
    np.testing.assert_array_equal(wrench['torque'][-1], WRENCH[3:])


def test_report_of_the_recording(recorded, tmp_path, capsys):
    assert report.main([str(recorded.bags['mcap']), '--out', str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert '/ (right arm)' in printed and 'missing' not in printed
    with open(tmp_path / 'mcap_samples.csv', newline='') as stream:
        rows = list(csv.reader(stream))[1:]
    store = typestore()
    states = [store.deserialize_cdr(bytes(d), JOINT_STATE)
              for _, d in recorded.received['/joint_states']]
    assert [int(row[0]) for row in rows] == [
        s.header.stamp.sec * 10**9 + s.header.stamp.nanosec for s in states]
    np.testing.assert_allclose([[float(x) for x in row[1:7]] for row in rows],
                               [s.position for s in states], atol=1e-9)
    efforts = np.array([[float(x) for x in row[13:19]] for row in rows])
    assert np.abs(efforts).max() > 0.01
    assert (tmp_path / 'mcap_report.png').stat().st_size > 10_000


class RecordCommand:
    """The installed kraft_master_record, its output collected line by line."""

    def __init__(self, prefix, domain_id, args):
        """Start it with `args`."""
        self.process = subprocess.Popen(
            [str(executable(prefix, 'kraft_master_record')), *args],
            env=installed_env(prefix, domain_id), stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True)
        self.lines = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self):
        for line in self.process.stdout:
            self.lines.append(line.rstrip('\n'))

    def counts(self, prefix=''):
        """Return {topic: count} of the last status line that starts with `prefix`."""
        lines = [line for line in self.lines if ' messages' in line and line.startswith(prefix)]
        counts = lines[-1].partition(' messages (')[2] if lines else ''
        return {topic: int(count) for topic, count in re.findall(r'(/\S+) (\d+)', counts)}

    def stop(self, sig):
        """Send `sig`; return the exit code."""
        self.process.send_signal(sig)
        self.process.wait(timeout=60)
        self.reader.join(timeout=10)
        return self.process.returncode

    def kill(self):
        """Make sure the process is gone (SIGTERM first: its DDS participant tears down)."""
        dds_shm.end(self.process)


@pytest.fixture(scope='module')
def right_arm(install_prefix):
    """Run the installed driver in /right on a simulated device; return (domain, hashes)."""
    domain_id = next_domain_id()
    simulator = SimulatedKraftMaster(arm='right', operator='sweep', operator_period=1.0)
    driver = DriverProcess(install_prefix, domain_id, [
        ('port', simulator.start()), ('arm', 'right'), ('loop_rate_hz', 200.0)],
        namespace='/right')
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node('type_hash_probe', context=context)
    try:
        infos = wait_for(lambda: node.get_publishers_info_by_topic('/right/joint_states'),
                         timeout=60.0)
        yield domain_id, {str(info.topic_type_hash) for info in infos}
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        driver.kill()
        simulator.stop()


ARM_TOPICS = ['/right/joint_states', '/right/pose', '/right/pots']


@pytest.mark.parametrize('sig, storage, selection', [
    (signal.SIGINT, 'mcap', ['--namespace', 'right']),
    (signal.SIGTERM, 'mcap', ['--namespace', 'right']),
    (signal.SIGTERM, 'sqlite3', ARM_TOPICS),
    (signal.SIGINT, 'sqlite3', ['-a'])])
def test_record_command_closes_a_complete_bag(install_prefix, right_arm, tmp_path, sig,
                                              storage, selection):
    domain_id, endpoint_hashes = right_arm
    bag = tmp_path / 'arm_session'
    recorder = RecordCommand(install_prefix, domain_id, [
        *selection, '-o', str(bag), '-s', storage, '--status-period', '0.2'])
    try:
        wait_for(lambda: recorder.counts().get('/right/joint_states', 0) >= 300 and (
            selection == ARM_TOPICS or
            any(recorder.counts().get(t) for t in ('/diagnostics', '/right/diagnostics'))),
            timeout=90.0)
        assert recorder.stop(sig) == 0, '\n'.join(recorder.lines)
    finally:
        recorder.kill()
    output = '\n'.join(recorder.lines)
    assert output.startswith(f'Recording into {bag} ({storage}): ' + {
        '-a': 'every topic', '--namespace': '/diagnostics '}.get(
            selection[0], ' '.join(ARM_TOPICS)))
    assert 'Subscribed to /right/pots (sensor_msgs/msg/JointState)' in output
    closed = recorder.counts(prefix=f'Closed {bag}: ')
    assert closed['/right/joint_states'] >= 300
    if selection == ARM_TOPICS:
        assert sorted(closed) == ARM_TOPICS
    if selection == ['-a']:
        assert {'/rosout', '/parameter_events', *ARM_TOPICS} <= set(closed)
    published = {topic: count for topic, count in closed.items() if count}
    assert sorted(p.name for p in bag.iterdir()) == sorted(
        ['metadata.yaml', f'arm_session_0.{"mcap" if storage == "mcap" else "db3"}'])

    store = typestore()
    read = collections.Counter()
    with Reader(bag) as reader:
        assert {c.topic: c.msgcount for c in reader.connections} == closed
        for connection, _, data in reader.messages():
            store.deserialize_cdr(data, connection.msgtype)
            read[connection.topic] += 1
    assert read == published
    (endpoint_hash,) = endpoint_hashes
    assert endpoint_hash == generated_type_hash(JOINT_STATE)

    if storage == 'sqlite3':
        database = sqlite3.connect(bag / 'arm_session_0.db3')
        hashes = dict(database.execute('SELECT name, type_description_hash FROM topics'))
        database.close()
        assert hashes['/right/joint_states'] == endpoint_hash
        return
    with open(bag / 'arm_session_0.mcap', 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        counts = collections.Counter()
        sequences = []
        for _, channel, message, decoded in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            if channel.topic == '/right/joint_states':
                sequences.append(message.sequence)
                assert channel.metadata['topic_type_hash'] == endpoint_hash
                assert list(decoded.name) == list(kinematics.JOINT_NAMES)
                stamp = decoded.header.stamp.sec * 10**9 + decoded.header.stamp.nanosec
                # Stamped at the sample, sent (publish time), then received (log time).
                assert stamp <= message.publish_time <= message.log_time
    assert counts == published
    # Each message keeps the driver's count of it (DDS's publication sequence number): rising,
    # by more than one only where the recorder lost some.
    assert sequences[0] >= 1 and min(np.diff(sequences)) >= 1, sequences[:20]


def test_record_selects_the_driver_topics_of_each_namespace():
    assert record.driver_topics(['right', 'left']) == ['/diagnostics'] + [
        f'/{arm}/{name}' for arm in ('left', 'right') for name in sorted(DRIVER_TOPICS)]
    assert record.driver_topics(['/']) == ['/diagnostics', '/joint_states', '/pose', '/pots',
                                           '/rate_command', '/wrench']


def endpoint(reliability, durability):
    """Return the TopicEndpointInfo of a publisher offering `reliability` and `durability`."""
    return TopicEndpointInfo(qos_profile=QoSProfile(depth=10, reliability=reliability,
                                                    durability=durability))


def test_record_subscribes_with_what_every_publisher_offers():
    reliable, best_effort = ReliabilityPolicy.RELIABLE, ReliabilityPolicy.BEST_EFFORT
    volatile, latched = DurabilityPolicy.VOLATILE, DurabilityPolicy.TRANSIENT_LOCAL
    for offered, expected in (
            ([(reliable, volatile)], (reliable, volatile)),
            ([(reliable, latched), (reliable, latched)], (reliable, latched)),
            ([(reliable, volatile), (best_effort, latched)], (best_effort, volatile)),
            ([(best_effort, volatile)], (best_effort, volatile))):
        qos = record.subscription_qos([endpoint(*policies) for policies in offered])
        assert (qos.reliability, qos.durability) == expected
        assert qos.depth == record.SUBSCRIPTION_DEPTH


def test_record_command_refuses_an_existing_bag_and_answers_help(install_prefix, tmp_path):
    bag = tmp_path / 'taken'
    bag.mkdir()
    (bag / 'keep').write_text('kept')
    env = installed_env(install_prefix, next_domain_id())
    command = str(executable(install_prefix, 'kraft_master_record'))
    result = subprocess.run([command, '-o', str(bag)], env=env, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 1
    assert result.stderr.strip().count('\n') == 0 and str(bag) in result.stderr
    assert (bag / 'keep').read_text() == 'kept' and len(list(bag.iterdir())) == 1
    result = subprocess.run([command, '--help'], env=env, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0 and 'usage: kraft_master_record' in result.stdout
