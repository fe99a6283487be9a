# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The installed kraft_master_teleop, driven by a stand-in master and arm in this process."""
import collections
import importlib.util
import math

from geometry_msgs.msg import PoseStamped, TwistStamped, Vector3Stamped, WrenchStamped
from harness.driver import DriverProcess, next_domain_id, RosClient, wait_for
import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Joy
from std_msgs.msg import Bool, String
from std_srvs.srv import SetBool, Trigger

pytestmark = pytest.mark.integration

TF2_ROS = importlib.util.find_spec('tf2_ros') is not None
ARM_HOME = np.array([0.4, 0.1, 0.3])
MASTER_START = np.array([0.12, -0.05, 0.2])
# Generous timeouts: the test's own publishing pace must never trip them on a loaded machine.
QUIET = [('master_timeout', '0.5'), ('arm_timeout', '2.0'), ('ft_timeout', '2.0'),
         ('max_linear_speed', '10.0')]


def positions(messages):
    """Return the positions of PoseStamped messages as an (n, 3) array."""
    return np.array([(m.pose.position.x, m.pose.position.y, m.pose.position.z)
                     for m in messages])


def forces(messages):
    """Return the forces of WrenchStamped messages as an (n, 3) array."""
    return np.array([(m.wrench.force.x, m.wrench.force.y, m.wrench.force.z) for m in messages])


class Rig:
    """A stand-in master and arm: the arm is wherever the bridge last commanded it."""

    def __init__(self, domain_id):
        """Join the domain with the master's and the arm's topics and the bridge's services."""
        self.client = RosClient(domain_id)
        node = self.client.node
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.servo_cp, self.servo_cv, self.wrenches, self.states = (
            collections.deque(maxlen=5000) for _ in range(4))
        self.cutoff = 0  # ns: what the bridge stamped earlier is forgotten (forget())
        for msg_type, topic, kept in ((PoseStamped, 'servo_cp', self.servo_cp),
                                      (TwistStamped, 'servo_cv', self.servo_cv),
                                      (WrenchStamped, 'wrench', self.wrenches)):
            node.create_subscription(msg_type, topic, lambda m, d=kept: self._keep(m, d),
                                     reliable)
        node.create_subscription(String, 'operating_state', lambda m: self.states.append(m.data),
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.pose_pub = node.create_publisher(PoseStamped, 'pose', reliable)
        self.energy_pub = node.create_publisher(Vector3Stamped, 'master_energy', reliable)
        self.arm_pub = node.create_publisher(PoseStamped, 'measured_cp', reliable)
        self.ft_pub = node.create_publisher(WrenchStamped, 'measured_cf', reliable)
        self.clutch_pub = node.create_publisher(Bool, 'clutch', reliable)
        self.joy_pub = node.create_publisher(Joy, 'joy', reliable)
        self.enable_client = node.create_client(SetBool, 'enable')
        self.tare_client = node.create_client(Trigger, 'tare')
        self.master = MASTER_START.copy()
        self.master_frame = 'kraft_master_base'
        self.arm_offset = np.zeros(3)  # the arm's error: where it is, less where it was sent
        self.reading = np.zeros(6)
        self.ft_frame = 'ft_sensor'
        self.streams = {'pose': True, 'measured_cp': True, 'measured_cf': True}

    def arm_position(self):
        """Return where the arm is: its last command (or home), plus its error."""
        base = positions([self.servo_cp[-1]])[0] if self.servo_cp else ARM_HOME
        return base + self.arm_offset

    def publish(self):
        """Publish one master pose, arm pose and F/T reading, each if its stream is on."""
        node = self.client.node
        stamp = node.get_clock().now().to_msg()
        for topic, publisher, frame, position in (
                ('pose', self.pose_pub, self.master_frame, self.master),
                ('measured_cp', self.arm_pub, 'base_link', self.arm_position())):
            if self.streams[topic]:
                msg = PoseStamped()
                msg.header.stamp, msg.header.frame_id = stamp, frame
                p = msg.pose.position
                p.x, p.y, p.z = (float(v) for v in position)
                msg.pose.orientation.w = 1.0
                publisher.publish(msg)
        if self.streams['measured_cf']:
            msg = WrenchStamped()
            msg.header.stamp, msg.header.frame_id = stamp, self.ft_frame
            f, m = msg.wrench.force, msg.wrench.torque
            f.x, f.y, f.z, m.x, m.y, m.z = (float(v) for v in self.reading)
            self.ft_pub.publish(msg)

    def run_until(self, condition):
        """Publish every few ms until `condition()` holds; return its value."""
        def publish_and_check():
            self.publish()
            return condition()
        return wait_for(publish_and_check, spin=lambda: self.client.spin(0.003))

    def state(self):
        """Return the last operating_state received, or None."""
        return self.states[-1] if self.states else None

    def call(self, client, request):
        """Call a service while publishing; return the response."""
        assert client.wait_for_service(timeout_sec=60.0)
        future = client.call_async(request)
        self.run_until(future.done)
        return future.result()

    def enable(self, on=True):
        """Call enable; return the response."""
        return self.call(self.enable_client, SetBool.Request(data=on))

    def connected(self):
        """Wait until the bridge hears every stream and its state has come."""
        self.run_until(lambda: self.state() and all(
            p.get_subscription_count() for p in (self.pose_pub, self.arm_pub, self.ft_pub,
                                                 self.clutch_pub)))

    def move_master(self, delta, steps=20):
        """Move the master by `delta` (m) in `steps` published steps."""
        start = self.master.copy()
        for step in range(1, steps + 1):
            self.master = start + np.asarray(delta) * step / steps
            self.publish()
            self.client.spin(0.003)

    def settled_command(self):
        """Publish until two servo_cp in a row agree; return that position."""
        self.run_until(lambda: len(self.servo_cp) > 2 and np.array_equal(
            *positions(list(self.servo_cp)[-2:])))
        return positions([self.servo_cp[-1]])[0]

    def _keep(self, msg, kept):
        stamp = msg.header.stamp
        if stamp.sec * 1_000_000_000 + stamp.nanosec >= self.cutoff:
            kept.append(msg)

    def forget(self):
        """Drop the commands and wrenches received so far, and any still on their way."""
        # The bridge stamps each when it sends it, on this machine's clock: what it stamped
        # before now was sent before now, whenever it comes.
        self.cutoff = self.client.node.get_clock().now().nanoseconds
        self.servo_cp.clear()
        self.servo_cv.clear()
        self.wrenches.clear()
        self.run_until(lambda: len(self.wrenches) > 3)

    def close(self):
        """Leave the domain."""
        self.client.close()


@pytest.fixture
def start_bridge(install_prefix):
    """Yield start(parameters, silent) -> (rig, bridge process) on a domain of their own."""
    started = []

    def start(parameters=(), silent=()):
        domain_id = next_domain_id()
        rig = Rig(domain_id)
        for stream in silent:
            rig.streams[stream] = False
        process = DriverProcess(install_prefix, domain_id, [*QUIET, *parameters],
                                name='kraft_master_teleop')
        started.append((rig, process))
        rig.connected()
        return rig, process

    yield start
    for rig, process in started:
        rig.close()
        process.kill()


def enabled(rig):
    """Enable and wait until following: the first servo_cp after enable has come."""
    rig.servo_cp.clear()
    response = rig.enable()
    assert response.success, response.message
    rig.run_until(lambda: rig.servo_cp)
    return rig


def test_nothing_moves_until_enable_and_enable_does_not_jump(start_bridge):
    rig, _ = start_bridge([('scale', '0.5')])
    assert rig.state() == 'DISABLED: not enabled'
    # The inputs flow, the master moves: no command reaches the arm.
    rig.move_master((0.05, 0.0, 0.0))
    rig.run_until(lambda: len(rig.wrenches) > 20)
    assert not rig.servo_cp
    assert not np.any(forces(rig.wrenches))

    enabled(rig)
    assert rig.state() == 'ENABLED'
    np.testing.assert_array_equal(positions(rig.servo_cp)[0], ARM_HOME)
    rig.move_master((0.0, 0.02, 0.0))
    rig.run_until(lambda: np.allclose(positions([rig.servo_cp[-1]])[0],
                                      ARM_HOME + (0.0, 0.01, 0.0), atol=1e-9))
    assert np.all(np.abs(np.diff(positions(rig.servo_cp), axis=0)) <= 0.0005 + 1e-12)


def test_clutch_holds_the_arm_frees_the_master_and_release_does_not_jump(start_bridge):
    rig, _ = start_bridge()
    enabled(rig)
    rig.reading = np.array([0.0, 0.0, 3.0, 0.0, 0.0, 0.0])
    rig.move_master((0.01, 0.0, 0.0))
    rig.run_until(lambda: forces([rig.wrenches[-1]])[0][2] == pytest.approx(3.0))
    held = rig.settled_command()

    rig.clutch_pub.publish(Bool(data=True))
    rig.run_until(lambda: rig.state() == 'CLUTCHED')
    rig.forget()
    rig.move_master((0.0, 0.08, -0.03))  # the operator repositions the hand
    rig.run_until(lambda: len(rig.servo_cp) > 5 and len(rig.wrenches) > 5)
    np.testing.assert_array_equal(positions(rig.servo_cp), np.tile(held, (len(rig.servo_cp), 1)))
    assert not np.any(forces(rig.wrenches))

    rig.clutch_pub.publish(Bool(data=False))
    rig.run_until(lambda: rig.state() == 'ENABLED')
    rig.servo_cp.clear()
    rig.move_master((0.0, 0.0, 0.01))
    rig.run_until(lambda: np.allclose(positions([rig.servo_cp[-1]])[0], held + (0, 0, 0.01),
                                      atol=1e-9))
    np.testing.assert_array_equal(positions(rig.servo_cp)[0], held)


def test_a_joy_button_clutches(start_bridge):
    rig, _ = start_bridge([('clutch_button', '2')])
    enabled(rig)
    rig.run_until(lambda: rig.joy_pub.get_subscription_count())
    rig.joy_pub.publish(Joy(buttons=[0, 0, 1]))
    rig.run_until(lambda: rig.state() == 'CLUTCHED')
    rig.joy_pub.publish(Joy(buttons=[0, 0, 0]))
    rig.run_until(lambda: rig.state() == 'ENABLED')


def test_a_stale_master_pose_holds_the_arm_and_its_return_does_not_jump(start_bridge):
    rig, _ = start_bridge([('master_timeout', '0.2')])
    enabled(rig)
    rig.move_master((0.01, 0.0, 0.0))
    held = rig.settled_command()
    rig.streams['pose'] = False
    rig.run_until(lambda: rig.state().startswith('ENABLED: holding: pose older'))
    rig.servo_cp.clear()
    rig.run_until(lambda: len(rig.servo_cp) > 5)
    np.testing.assert_array_equal(positions(rig.servo_cp), np.tile(held, (len(rig.servo_cp), 1)))
    rig.master += (0.05, 0.05, 0.0)  # the master comes back elsewhere
    rig.streams['pose'] = True
    rig.run_until(lambda: rig.state() == 'ENABLED')
    rig.move_master((0.0, -0.01, 0.0))
    rig.run_until(lambda: np.allclose(positions([rig.servo_cp[-1]])[0], held + (0, -0.01, 0),
                                      atol=1e-9))
    assert np.all(np.abs(np.diff(positions(rig.servo_cp), axis=0)) <= 0.0005 + 1e-12)


def test_a_stale_force_reading_is_a_fault_with_zero_wrench(start_bridge):
    rig, _ = start_bridge([('ft_timeout', '0.3')])
    enabled(rig)
    rig.reading = np.array([0.0, 2.0, 0.0, 0.0, 0.0, 0.0])
    rig.run_until(lambda: forces([rig.wrenches[-1]])[0][1] == pytest.approx(2.0))
    rig.streams['measured_cf'] = False
    rig.run_until(lambda: rig.state() == 'FAULT: measured_cf older than ft_timeout 0.3 s')
    rig.forget()
    rig.run_until(lambda: len(rig.wrenches) > 5)
    assert not np.any(forces(rig.wrenches))


@pytest.mark.parametrize('fault, fragment', [
    ('nan', 'measured_cf refused: not finite'),
    ('huge', 'measured_cf refused: |f| 5000 N'),
    ('frame', "pose refused: frame_id 'kraft_master_wrist' is not 'kraft_master_base'"),
])
def test_a_bad_input_is_refused_in_one_line_and_is_a_fault(start_bridge, fault, fragment):
    rig, process = start_bridge()
    enabled(rig)
    held = rig.settled_command()
    if fault == 'nan':
        rig.reading = np.array([math.nan, 0.0, 0.0, 0.0, 0.0, 0.0])
    elif fault == 'huge':
        rig.reading = np.array([0.0, 0.0, 5000.0, 0.0, 0.0, 0.0])
    else:
        rig.master_frame = 'kraft_master_wrist'
    rig.run_until(lambda: rig.state().startswith('FAULT: ') and fragment in rig.state())
    rig.forget()
    rig.run_until(lambda: len(rig.servo_cp) > 5 and len(rig.wrenches) > 5)
    np.testing.assert_array_equal(positions(rig.servo_cp), np.tile(held, (len(rig.servo_cp), 1)))
    assert not np.any(forces(rig.wrenches))
    _, output = process.interrupt()
    assert [line for line in output.splitlines() if fragment in line]


def test_a_tracking_error_holds_the_arm_where_it_is_and_is_a_fault(start_bridge):
    rig, _ = start_bridge([('max_tracking_error', '0.01')])
    enabled(rig)
    held = rig.settled_command()
    rig.arm_offset = np.array([0.0, 0.0, -0.02])  # the arm sags 2 cm off its command
    rig.run_until(lambda: 'beyond max_tracking_error 0.01 m' in rig.state())
    rig.servo_cp.clear()
    rig.run_until(lambda: len(rig.servo_cp) > 5)
    np.testing.assert_allclose(positions(rig.servo_cp)[-1], held + (0.0, 0.0, -0.02),
                               atol=1e-12)


def test_tare_zeroes_the_bias(start_bridge):
    rig, _ = start_bridge()
    enabled(rig)
    rig.reading = np.array([1.5, 0.0, -2.0, 0.0, 0.0, 0.0])
    rig.run_until(lambda: np.allclose(forces([rig.wrenches[-1]])[0], [1.5, 0.0, -2.0]))
    response = rig.call(rig.tare_client, Trigger.Request())
    assert response.success, response.message
    rig.run_until(lambda: not np.any(forces([rig.wrenches[-1]])[0]))
    rig.reading = np.array([1.5, 0.0, 0.0, 0.0, 0.0, 0.0])
    rig.run_until(lambda: np.allclose(forces([rig.wrenches[-1]])[0], [0.0, 0.0, 2.0]))


def test_enable_is_refused_without_the_inputs(start_bridge):
    rig, _ = start_bridge(silent=['measured_cf'])
    response = rig.enable()
    assert not response.success
    assert 'no fresh measured_cf' in response.message
    assert rig.state() == 'DISABLED: not enabled'


def test_enable_at_start_waits_for_the_inputs_then_enables_once(start_bridge):
    rig, process = start_bridge([('enable_at_start', 'true')], silent=['measured_cf'])
    # Every input but the F/T reading: still DISABLED, nothing sent to the arm.
    rig.run_until(lambda: len(rig.wrenches) > 20)
    assert rig.state() == 'DISABLED: not enabled' and not rig.servo_cp
    rig.streams['measured_cf'] = True
    rig.run_until(lambda: rig.state() == 'ENABLED' and rig.servo_cp)
    np.testing.assert_array_equal(positions(rig.servo_cp)[0], ARM_HOME)
    # Once: disabled, it stays so.
    assert rig.enable(False).success
    rig.forget()
    rig.run_until(lambda: len(rig.wrenches) > 20)
    assert rig.state() == 'DISABLED: disabled' and not rig.servo_cp
    # The start-up banner comes before the bridge enables itself.
    _, output = process.interrupt()
    lines = output.splitlines()
    banner = next(i for i, line in enumerate(lines) if 'DISABLED until the enable' in line)
    assert banner < next(i for i, line in enumerate(lines) if 'enabled at start: ' in line)


def test_twist_mode_drives_toward_the_target_and_stops_when_clutched(start_bridge):
    rig, _ = start_bridge([('mode', 'twist'), ('twist_gain', '10.0')])
    assert rig.enable().success
    rig.run_until(lambda: rig.servo_cv)
    rig.arm_offset = np.array([-0.01, 0.0, 0.0])  # the arm falls 1 cm behind its target
    rig.run_until(lambda: rig.servo_cv and rig.servo_cv[-1].twist.linear.x == pytest.approx(
        0.1, abs=1e-9))
    assert rig.servo_cv[-1].header.frame_id == 'base_link'
    rig.clutch_pub.publish(Bool(data=True))
    rig.run_until(lambda: rig.state() == 'CLUTCHED')
    rig.forget()
    rig.run_until(lambda: len(rig.servo_cv) > 3)
    assert all(m.twist.linear.x == 0.0 for m in rig.servo_cv)


@pytest.mark.parametrize('name, value, fragment', [
    ('mode', 'sideways', 'mode'),
    ('base_rotation', '[0.0, 1.0]', 'base_rotation'),
    ('scael', '2.0', 'did you mean scale?'),
    ('workspace_min', '[3.0, 0.0, 0.0]', 'workspace_min'),
])
def test_a_bad_parameter_exits_1_naming_it(install_prefix, name, value, fragment):
    process = DriverProcess(install_prefix, next_domain_id(), [(name, value)],
                            name='kraft_master_teleop')
    code, output = process.wait_exit()
    assert code == 1, output
    assert fragment in output and len(output.strip().splitlines()) == 1


@pytest.mark.skipif(TF2_ROS, reason='tf2_ros is installed here: this refusal cannot happen')
def test_base_rotation_from_tf_without_tf2_ros_exits_1_saying_so(install_prefix):
    process = DriverProcess(install_prefix, next_domain_id(), [('base_rotation_from_tf', 'true')],
                            name='kraft_master_teleop')
    code, output = process.wait_exit()
    assert code == 1, output
    assert 'base_rotation_from_tf needs tf2_ros' in output
    assert len(output.strip().splitlines()) == 1


@pytest.mark.skipif(not TF2_ROS, reason='tf2_ros and tf2_msgs are not on PyPI: they cannot be '
                    'installed on this machine')
def test_base_rotation_from_tf_turns_master_motion_at_enable(start_bridge):
    from geometry_msgs.msg import TransformStamped
    from tf2_msgs.msg import TFMessage
    rig, _ = start_bridge([('base_rotation_from_tf', 'true')])
    static = rig.client.node.create_publisher(TFMessage, '/tf_static', QoSProfile(
        depth=1, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    transform = TransformStamped()
    transform.header.frame_id, transform.child_frame_id = 'base_link', 'kraft_master_base'
    transform.transform.rotation.z = transform.transform.rotation.w = math.sqrt(0.5)
    static.publish(TFMessage(transforms=[transform]))
    # Enable is refused until the bridge has heard the transform.
    rig.run_until(lambda: rig.enable().success)
    rig.run_until(lambda: rig.servo_cp)
    rig.move_master((0.02, 0.0, 0.0))
    # The master's +x is the arm's +y.
    rig.run_until(lambda: np.allclose(positions([rig.servo_cp[-1]])[0],
                                      ARM_HOME + (0.0, 0.02, 0.0), atol=1e-9))
