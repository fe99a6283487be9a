# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The installed driver (port:=sim) under CRTK names: measured_js, measured_cp and servo_cf."""
import math
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, WrenchStamped
from harness.driver import DriverProcess, next_domain_id, RosClient
from kraft_master_driver.core import kinematics
import numpy as np
import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

pytestmark = pytest.mark.integration

BASE, WRIST = 'kraft_master_base', 'kraft_master_wrist'
WRENCH = (3.0, -2.0, 4.0, 0.05, -0.1, 0.08)
# Joint states that must all carry zero torque once a refusal has taken hold.
HELD_STATES = 200


class CrtkSession:
    """The installed driver with its built-in simulated device, and a CRTK client node."""

    def __init__(self, prefix, crtk_names=True):
        """Start the driver (force on at start-up) and wait until it publishes and listens."""
        self.domain_id = next_domain_id()
        self.driver = DriverProcess(prefix, self.domain_id, [
            ('port', 'sim'), ('crtk_names', str(crtk_names).lower()),
            ('force_enabled_at_start', 'true')])
        self.client = client = RosClient(self.domain_id)
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.measured_js = client._record(JointState, 'measured_js', 2000, reliable)
        self.measured_cp = client._record(PoseStamped, 'measured_cp', 2000, reliable)
        self.statuses = []
        # Whether each joint state carried torque, every one since the start (no deque's cap).
        self.torques = []
        client.node.create_subscription(
            JointState, 'joint_states', lambda msg: self.torques.append(any(msg.effort)),
            reliable)
        client.node.create_subscription(DiagnosticArray, '/diagnostics',
                                        lambda msg: self.statuses.extend(msg.status), 10)
        self.servo_cf = client.node.create_publisher(
            WrenchStamped, 'servo_cf',
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        try:
            client.wait(lambda: client.joint_states)
            if crtk_names:
                client.wait(lambda: self.servo_cf.get_subscription_count() > 0)
        except AssertionError:
            self.close()
            raise

    def send(self, wrench=WRENCH, frame_id='', stamp_offset_s=None):
        """Publish one servo_cf: unstamped (as a CRTK client leaves it) or stamped now + offset."""
        msg = WrenchStamped()
        if stamp_offset_s is not None:
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(
                time.time_ns() + int(stamp_offset_s * 1e9), 1_000_000_000)
        msg.header.frame_id = frame_id
        f, m = msg.wrench.force, msg.wrench.torque
        f.x, f.y, f.z, m.x, m.y, m.z = (float(v) for v in wrench)
        self.servo_cf.publish(msg)

    def stream_until(self, condition, **wrench):
        """Publish servo_cf every few ms until `condition()` holds."""
        def sent_and_checked():
            self.send(**wrench)
            return condition()
        return self.client.wait(sent_and_checked)

    def torque_on(self):
        return bool(self.torques) and self.torques[-1]

    def torques_over(self, count, **wrench):
        """Stream servo_cf until `count` more joint states came; return their torque flags."""
        since = len(self.torques)
        self.stream_until(lambda: len(self.torques) >= since + count, **wrench)
        return self.torques[since:]

    def close(self):
        self.client.close()
        self.driver.kill()


@pytest.fixture(scope='module')
def crtk(install_prefix):
    """One driver with crtk_names for the module; each test starts from a steady servo_cf."""
    session = CrtkSession(install_prefix)
    yield session
    session.close()


def stamp(msg):
    return msg.header.stamp.sec, msg.header.stamp.nanosec


def same_stamp_pairs(originals, copies):
    """Return (original, copy) of the messages received under both names with one stamp."""
    by_stamp = {stamp(m): m for m in list(originals)}
    return [(by_stamp[stamp(m)], m) for m in list(copies) if stamp(m) in by_stamp]


def test_measured_js_and_measured_cp_carry_what_joint_states_and_pose_carry(crtk):
    client = crtk.client

    def enough():
        # This client keeps up with part of 1 kHz only: each name loses other messages.
        pairs = same_stamp_pairs(client.joint_states, crtk.measured_js)
        return (len(pairs) > 50 and any(any(m.effort) for _, m in pairs) and
                len(same_stamp_pairs(client.poses, crtk.measured_cp)) > 50)
    crtk.stream_until(enough)
    for state, measured in same_stamp_pairs(client.joint_states, crtk.measured_js):
        assert measured.header.frame_id == state.header.frame_id == BASE
        assert list(measured.name) == list(state.name) == list(kinematics.JOINT_NAMES)
        assert (list(measured.position), list(measured.velocity), list(measured.effort)) == (
            list(state.position), list(state.velocity), list(state.effort))
    for pose, measured in same_stamp_pairs(client.poses, crtk.measured_cp):
        assert measured.header.frame_id == BASE
        assert measured.pose == pose.pose


@pytest.mark.parametrize('frame_id', ['', BASE, WRIST])
def test_servo_cf_gives_the_torques_j_transpose_f(crtk, frame_id):
    client = crtk.client
    # A state stamped well after the first of these wrenches: none before counts.
    after_ns = time.time_ns() + 100_000_000

    def newest_with_torque():
        state = client.joint_states[-1]
        sec, nanosec = stamp(state)
        return any(state.effort) and sec * 1_000_000_000 + nanosec > after_ns and state
    state = crtk.stream_until(newest_with_torque, frame_id=frame_id)
    force, moment = np.array(WRENCH[:3]), np.array(WRENCH[3:])
    if frame_id == WRIST:
        rotation = kinematics.forward(state.position)[:3, :3]
        force, moment = rotation @ force, rotation @ moment
    expected = kinematics.jacobian(state.position).T @ np.concatenate([force, moment])
    expected[5] = 0.0
    np.testing.assert_allclose(state.effort, expected, atol=2e-3)


def assert_held_at_zero(crtk, **bad):
    """Stream a bad servo_cf: torque goes to zero and stays there; a good one brings it back."""
    crtk.stream_until(crtk.torque_on)
    crtk.stream_until(lambda: not crtk.torque_on(), **bad)
    assert not any(crtk.torques_over(HELD_STATES, **bad)), 'a refused servo_cf gave torque'
    crtk.stream_until(crtk.torque_on)


@pytest.mark.parametrize('bad', [
    {'wrench': (math.nan, 0.0, 0.0, 0.0, 0.0, 0.0)},
    {'wrench': (0.0, 0.0, 0.0, 0.0, 0.0, math.inf)},
    {'wrench': (1e9, 0.0, 0.0, 0.0, 0.0, 0.0)},
    {'frame_id': 'map'},
    {'frame_id': BASE, 'stamp_offset_s': -3600.0},
    {'frame_id': BASE, 'stamp_offset_s': -0.5},  # older than max_wrench_age
], ids=['NaN force', 'infinite moment', '1e9 N force', 'unknown frame', 'stamp 1 h old',
        'stamp 0.5 s old'])
def test_a_bad_servo_cf_is_refused_with_zero_torque(crtk, bad):
    assert_held_at_zero(crtk, **bad)


def test_servo_cf_that_stops_zeroes_the_torque(crtk):
    client = crtk.client
    crtk.stream_until(crtk.torque_on)
    client.wait(lambda: not crtk.torque_on())  # wrench_timeout, nothing sent meanwhile
    since = len(crtk.torques)
    client.wait(lambda: len(crtk.torques) >= since + HELD_STATES)
    assert not any(crtk.torques[since:])


def test_a_publisher_on_wrench_and_one_on_servo_cf_are_two_sources(crtk):
    client = crtk.client
    crtk.stream_until(crtk.torque_on)
    second = client.node.create_publisher(
        WrenchStamped, 'wrench', QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
    try:
        since = len(crtk.statuses)
        crtk.stream_until(lambda: not crtk.torque_on() and len(crtk.statuses) > since + 1)
        status = crtk.statuses[-1]
        assert status.message == (
            'torques zero: 2 publishers on /wrench and /servo_cf, only one wrench source is '
            'allowed (allow_multiple_wrench_sources)')
        assert not any(crtk.torques_over(HELD_STATES))
    finally:
        client.node.destroy_publisher(second)
    crtk.stream_until(crtk.torque_on)


def test_without_crtk_names_there_is_no_crtk_topic(install_prefix):
    session = CrtkSession(install_prefix, crtk_names=False)
    try:
        node = session.client.node
        session.client.wait(lambda: node.get_publishers_info_by_topic('/joint_states'))
        assert node.get_subscriptions_info_by_topic('/wrench')
        assert not node.get_publishers_info_by_topic('/measured_js')
        assert not node.get_publishers_info_by_topic('/measured_cp')
        assert not node.get_subscriptions_info_by_topic('/servo_cf')
    finally:
        session.close()
