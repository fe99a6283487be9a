# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The installed driver (port:=sim) under CRTK names: measured_js, measured_cp and servo_cf."""
import bisect
import math
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, WrenchStamped
from harness.driver import DriverProcess, next_domain_id, RosClient, wait_for
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
# The client takes messages for this long between two servo_cf and two checks (s): checking
# after every message, it fell so far behind its six 1 kHz streams that the same stamp rarely
# reached it under two names (no 50 pairs in 120 s).
SEND_PERIOD_S = 0.002
# The driver's rate here (Hz). At 1 kHz, with a busy loop per core, this client took one
# message in about twelve of each name, and pairs with one stamp, which need it to take the
# same message twice, came so rarely that 50 took over 120 s; at 200 Hz, with three busy
# loops, it took them all.
LOOP_RATE_HZ = 200.0


class CrtkSession:
    """The installed driver with its built-in simulated device, and a CRTK client node."""

    def __init__(self, prefix, crtk_names=True):
        """Start the driver (force on at start-up) and wait until it publishes and listens."""
        self.domain_id = next_domain_id()
        self.driver = DriverProcess(prefix, self.domain_id, [
            ('port', 'sim'), ('crtk_names', str(crtk_names).lower()),
            ('force_enabled_at_start', 'true'), ('loop_rate_hz', LOOP_RATE_HZ)])
        self.client = client = RosClient(self.domain_id)
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.measured_js = client._record(JointState, 'measured_js', 2000, reliable)
        self.measured_cp = client._record(PoseStamped, 'measured_cp', 2000, reliable)
        # (stamp ns, status) of each diagnostic status: the stamp is when it was published.
        self.statuses = []
        # (stamp ns, whether it carried torque) of every joint state since the start.
        self.torques = []
        client.node.create_subscription(
            JointState, 'joint_states',
            lambda msg: self.torques.append((stamp_ns(msg), any(msg.effort))), reliable)
        client.node.create_subscription(
            DiagnosticArray, '/diagnostics',
            lambda msg: self.statuses.extend((stamp_ns(msg), s) for s in msg.status), 10)
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

    def stream_until(self, condition, send=True, **wrench):
        """Publish servo_cf (unless not `send`) every few ms until `condition()` holds."""
        def sent_and_checked():
            if send:
                self.send(**wrench)
            return condition()
        return wait_for(sent_and_checked, spin=lambda: self.client.spin(SEND_PERIOD_S))

    def torque_on(self):
        return bool(self.torques) and self.torques[-1][1]

    def torques_after(self, since_ns, refused=False, send=True, **wrench):
        """
        Return the torque flags of HELD_STATES joint states that came after since_ns.

        refused: since_ns is a moment from which on every state must carry no torque. Else
        since_ns is when a refused input began to be sent, and the states counted follow the
        first HELD_STATES states stamped after it in a row without torque (a state without
        torque can also come of a late cycle before the refused input arrived). This client
        may lag the driver by many states: only the stamps say which came after; the states
        arrive in the order of their stamps, and those stamped before since_ns may still
        arrive after since_ns is known (since_ns from a diagnostics message that overtook them).
        """
        scan, run_start, end = [None], [None], [None]

        def found():
            if scan[0] is None:
                scan[0] = bisect.bisect_right(self.torques, (since_ns, True))
            while scan[0] < len(self.torques):
                index, (stamp, torque) = scan[0], self.torques[scan[0]]
                scan[0] += 1
                if stamp <= since_ns:
                    continue  # it arrived after since_ns was known, but was sent before
                if refused:
                    end[0] = index
                    return True
                run_start[0] = None if torque else (
                    index if run_start[0] is None else run_start[0])
                if run_start[0] is not None and index - run_start[0] + 1 >= HELD_STATES:
                    end[0] = index + 1
                    return True
            return False
        self.stream_until(found, send, **wrench)
        start = end[0]
        self.stream_until(lambda: len(self.torques) >= start + HELD_STATES, send, **wrench)
        return [on for _, on in self.torques[start:start + HELD_STATES]]

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


def stamp_ns(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


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
        # The torque a state carries was worked out a cycle before, from the pose then: take a
        # state of a hand that has come to rest under the wrench.
        previous, state = list(client.joint_states)[-2:]
        still = np.abs(np.subtract(state.position, previous.position)).max() < 1e-5
        ramped_in = np.allclose(state.effort, previous.effort, atol=1e-5)
        return any(state.effort) and still and ramped_in and stamp_ns(state) > after_ns and state
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
    since_ns = time.time_ns()
    assert not any(crtk.torques_after(since_ns, **bad)), 'a refused servo_cf gave torque'
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
    crtk.stream_until(crtk.torque_on)
    since_ns = time.time_ns()
    assert not any(crtk.torques_after(since_ns, send=False))  # wrench_timeout after the last


def test_a_publisher_on_wrench_and_one_on_servo_cf_are_two_sources(crtk):
    client = crtk.client
    crtk.stream_until(crtk.torque_on)
    second = client.node.create_publisher(
        WrenchStamped, 'wrench', QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
    expected = ('torques zero: 2 publishers on /wrench and /servo_cf, only one wrench source '
                'is allowed (allow_multiple_wrench_sources)')
    try:
        refused_at = crtk.stream_until(lambda: next(
            (stamp for stamp, status in reversed(crtk.statuses) if status.message == expected),
            None))
        # Every state after a status that says so carries no torque.
        torques = crtk.torques_after(refused_at, refused=True)
        # On failure, what the driver said since (once, a fresh-clone run saw torque here).
        said = [(stamp - refused_at, status.message,
                 next((kv.value for kv in status.values if kv.key == 'wrench sources'), None))
                for stamp, status in crtk.statuses if stamp >= refused_at]
        assert not any(torques), f'{sum(torques)} of {len(torques)} with torque; since: {said}'
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
