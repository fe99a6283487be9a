# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The installed kraft_master_teleop, driven by a stand-in master and arm in this process."""
import collections
import importlib.util
import math

from geometry_msgs.msg import PoseStamped, TwistStamped, Vector3Stamped, WrenchStamped
from harness.driver import DriverProcess, next_domain_id, RosClient, wait_for, WAIT_S
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration
from kraft_master_driver.core.teleoperation_tuning import RAMP_S
from kraft_master_driver.nodes.teleop_parameters import PARAMETERS
from kraft_master_driver.simulation.master.model import Workspace
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
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
    """Enable and wait until following: 'ENABLED', and the first servo_cp after enable."""
    rig.servo_cp.clear()

    def answered():
        # Matched on the rig's side is not yet heard on the bridge's: until every input has
        # reached the bridge, enable says 'no fresh ...'; any other answer is the answer.
        response = rig.enable()
        return response if response.success or 'no fresh' not in response.message else None
    response = rig.run_until(answered)
    assert response.success, response.message
    rig.run_until(lambda: rig.servo_cp and rig.state() == 'ENABLED')
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
    # Following once the master is sent the arm's contact: registered where the arm is.
    rig.reading = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    rig.run_until(lambda: rig.servo_cv and rig.wrenches
                  and forces([rig.wrenches[-1]])[0][2] == pytest.approx(1.0))
    rig.reading = np.zeros(6)
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
    ('workspace_max', '[5.0, 5.0]', 'parameter workspace_max: expected 3 values, got 2'),
    ('workspace_max', '[5.0]', 'parameter workspace_max: expected 3 values, got 1'),
    ('workspace_min', '[-1.0, -1.0]', 'parameter workspace_min: expected 3 values, got 2'),
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
    # base_rotation is TF's: a set of it is refused.
    parameters = AsyncParameterClient(rig.client.node, '/kraft_master_teleop')
    assert parameters.wait_for_services(timeout_sec=WAIT_S)
    result = set_while_moving(rig, parameters, 'base_rotation', [0.0, 0.0, 0.0])
    assert (result.successful, result.reason) == (
        False, 'parameter base_rotation is taken from TF (base_rotation_from_tf)')


# -- parameters set while following -----------------------------------------------------------

# A new value of every parameter settable at run time, none stricter than the rig can meet.
RUN_TIME_VALUES = {
    'scale': 2.0, 'orientation': 'fixed', 'base_rotation': [0.0, 0.0, 0.3],
    'sensor_rotation': [0.0, 0.0, 0.5], 'workspace_min': [-1.0, -1.0, -1.0],
    'workspace_max': [1.0, 1.0, 1.0], 'max_linear_speed': 1.0, 'max_angular_speed': 2.0,
    'twist_gain': 20.0, 'master_timeout': 1.0, 'arm_timeout': 3.0, 'ft_timeout': 3.0,
    'max_tracking_error': 0.1, 'max_tracking_angle': 0.6, 'tool_mass': 0.5,
    'tool_com': [0.0, 0.0, 0.05], 'gravity': [0.0, 0.0, -9.8], 'force_scale': 3.0,
    'moment_scale': 0.5, 'force_deadband': 1.0, 'moment_deadband': 0.1, 'force_cutoff_hz': 5.0,
    'max_force': 2.0, 'max_moment': 0.2, 'arm_stiffness': 2000.0, 'max_input_force': 500.0,
    'max_input_moment': 50.0, 'max_input_position': 5.0, 'passivity': True, 'drift_gain': 5.0,
    'slave_port_force': 'sent', 'force_feedback': False, 'model_tolerance': 5.0,
    'force_resume_time': 0.2, 'arm_hold_timeout': 1.0}
# A steady contact along z, across the master's motion along x (no work for passivity to
# book), with a moment about z.
PRESSED = np.array([0.0, 0.0, 4.0, 0.0, 0.0, 0.2])
MASTER_STEP = np.array([5e-6, 0.0, 0.0])  # m per published pose


def pot_count_travel():
    """Return the least wrist travel (m) of one count of POT1..POT3 at the master's home."""
    calibration = ArmCalibration.nominal('right')
    theta = Workspace().home()
    pots = calibration.joints_to_pots(theta)
    home = kinematics.forward(theta, 'right')[:3, 3]
    return min(np.linalg.norm(kinematics.forward(calibration.pots_to_joints(
        pots + np.eye(6)[pot]), 'right')[:3, 3] - home) for pot in range(3))


POT_COUNT_TRAVEL = pot_count_travel()  # about 0.14 mm
# The wrench is ramped on the bridge's monotonic clock and stamped on its system clock, a
# moment apart: two wrenches may be this much further apart on the one than on the other (s).
STAMP_SLACK_S = 0.05


def wrench_values(messages):
    """Return the forces and moments of WrenchStamped messages as an (n, 6) array."""
    return np.array([(m.wrench.force.x, m.wrench.force.y, m.wrench.force.z,
                      m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z)
                     for m in messages])


def stamps(messages):
    """Return the header stamps of messages in seconds."""
    return np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in messages])


def since(messages, start):
    """Return the messages stamped at or after `start` (s)."""
    return [m for m, stamp in zip(messages, stamps(messages)) if stamp >= start]


def moving_until(rig, condition):
    """Publish, the master moving on by MASTER_STEP each time, until `condition()` holds."""
    def step_and_check():
        rig.master = rig.master + MASTER_STEP
        rig.publish()
        return condition()
    return wait_for(step_and_check, spin=lambda: rig.client.spin(0.003))


def set_while_moving(rig, parameters, name, value):
    """Set parameter `name` while the master moves; return the SetParametersResult."""
    future = parameters.set_parameters([Parameter(name, value=value)])
    moving_until(rig, future.done)
    return future.result().results[0]


@pytest.fixture
def following(start_bridge):
    """Yield (rig, parameter client): following, the master moved 5 cm, pressed by PRESSED."""
    rig, _ = start_bridge([('max_force', '20.0'), ('max_moment', '2.0')])
    # Until the bridge has heard every stream: matched on the rig's side is not yet on its own.
    rig.run_until(lambda: rig.enable().success)
    rig.run_until(lambda: rig.servo_cp)
    rig.move_master((0.05, 0.0, 0.0))  # far from where it registered
    rig.reading = PRESSED
    rig.run_until(lambda: np.allclose(wrench_values([rig.wrenches[-1]])[0], PRESSED))
    parameters = AsyncParameterClient(rig.client.node, '/kraft_master_teleop')
    assert parameters.wait_for_services(timeout_sec=WAIT_S)
    yield rig, parameters


def test_run_time_values_cover_every_settable_parameter():
    assert set(RUN_TIME_VALUES) == {name for name, spec in PARAMETERS.items()
                                    if not spec.read_only}


@pytest.mark.slow
def test_every_run_time_parameter_is_set_while_following_without_a_jump_or_a_kick(following):
    rig, parameters = following
    worst = (0.0, '')
    for name, value in RUN_TIME_VALUES.items():
        # Not rig.forget(): the rig's arm is where the last kept servo_cp sent it.
        start = rig.client.node.get_clock().now().nanoseconds * 1e-9
        moving_until(rig, lambda: len(since(rig.wrenches, start)) > 3)
        result = set_while_moving(rig, parameters, name, value)
        assert result.successful, f'{name}: {result.reason}'
        ramped_at = rig.client.node.get_clock().now().nanoseconds * 1e-9 + RAMP_S
        moving_until(rig, lambda: stamps(rig.wrenches)[-1] > ramped_at)
        assert rig.state() == 'ENABLED', f'{name}: {rig.state()}'
        commands, wrenches = since(rig.servo_cp, start), since(rig.wrenches, start)
        steps = np.linalg.norm(np.diff(positions(commands), axis=0), axis=1)
        assert steps.max() < POT_COUNT_TRAVEL, f'{name}: the target jumped {steps.max():.6f} m'
        times, wrenches = stamps(wrenches), wrench_values(wrenches)
        change = np.abs(wrenches[-1] - wrenches[0])
        # 1 uN beyond the ramp: the low-pass (force_cutoff_hz, set before) still settles by
        # about 3e-7 N a step half a second on, no kick.
        allowed = np.outer(np.diff(times) + STAMP_SLACK_S, change) / RAMP_S + 1e-6
        kicks = np.abs(np.diff(wrenches, axis=0))
        assert np.all(kicks <= allowed), (
            f'{name}: the wrench stepped {kicks.max(axis=0).tolist()} of {change.tolist()}')
        changed = change > 1e-6
        if np.any(changed):
            worst = max(worst, (np.max(kicks[:, changed] / change[changed]), name))
    print(f'largest wrench step: {worst[0]:.3f} of a change ({worst[1]}); target steps under '
          f'{1e3 * POT_COUNT_TRAVEL:.3f} mm')
    (value,) = call_parameters(rig, parameters.get_parameters(['force_feedback'])).values
    assert value.bool_value is False


def call_parameters(rig, future):
    """Publish until `future` is done; return its result."""
    rig.run_until(future.done)
    return future.result()


@pytest.mark.parametrize('name, value, reason', [
    ('workspace_min', [3.0, 3.0, 3.0], 'parameter workspace_min must be below workspace_max on '
     'every axis, got [3.0, 3.0, 3.0] and [2.0, 2.0, 2.0]'),
    ('base_rotation', [0.0, 0.0, 0.0, 2.0], 'parameter base_rotation: the quaternion '
     '[0.0, 0.0, 0.0, 2.0] is not of unit length'),
    ('orientation', 'loose', "parameter orientation: 'loose' is not one of follow, fixed, "
     'ignore'),
    ('mode', 'twist', 'Trying to set a read-only parameter: mode.'),
    ('workspace_max', [5.0, 5.0], 'parameter workspace_max: expected 3 values, got 2'),
])
def test_a_refused_set_changes_nothing(following, name, value, reason):
    rig, parameters = following
    (before,) = call_parameters(rig, parameters.get_parameters([name])).values
    start = rig.client.node.get_clock().now().nanoseconds * 1e-9
    result = set_while_moving(rig, parameters, name, value)
    assert (result.successful, result.reason) == (False, reason)
    (after,) = call_parameters(rig, parameters.get_parameters([name])).values
    assert after == before
    # Still following at scale 1 along x, the same wrench.
    moving_until(rig, lambda: len(since(rig.servo_cp, start)) > 10)
    steps = np.diff(positions(since(rig.servo_cp, start)), axis=0)
    np.testing.assert_allclose(steps[:, 1:], 0.0, atol=1e-12)
    assert steps[:, 0].max() < POT_COUNT_TRAVEL
    np.testing.assert_allclose(wrench_values(since(rig.wrenches, start)) - PRESSED, 0.0,
                               atol=1e-12)
    assert rig.state() == 'ENABLED'
