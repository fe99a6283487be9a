# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The installed simulated arm on its own, fed by a stand-in for the bridge's arm-side topics."""
import collections
import math
import signal

from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from harness.driver import next_domain_id, RosClient, slave_process, vector_parameter, wait_for
import numpy as np
import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy

ARM_FRAME, FT_FRAME = 'base_link', 'ft_sensor'  # the bridge's defaults, the arm's too


class Bridge:
    """A stand-in for the bridge: publishes servo_cp or servo_cv, records what the arm says."""

    def __init__(self, domain_id):
        """Join the domain; record measured_cp and measured_cf."""
        self.domain_id = domain_id
        self.client = RosClient(domain_id)
        node = self.client.node
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.wrenches = collections.deque(maxlen=2000)
        self.poses = collections.deque(maxlen=2000)
        node.create_subscription(
            WrenchStamped, 'measured_cf', lambda msg: self.wrenches.append(msg), qos)
        node.create_subscription(
            PoseStamped, 'measured_cp', lambda msg: self.poses.append(msg), qos)
        self.pose_pub = node.create_publisher(PoseStamped, 'servo_cp', qos)
        self.twist_pub = node.create_publisher(TwistStamped, 'servo_cv', qos)

    def publish_pose(self, position, frame_id=ARM_FRAME):
        """Publish a target at `position`, orientation a quarter turn about z."""
        msg = PoseStamped()
        msg.header.frame_id = frame_id
        p, q = msg.pose.position, msg.pose.orientation
        p.x, p.y, p.z = (float(v) for v in position)
        q.z = q.w = math.sqrt(0.5)
        self.pose_pub.publish(msg)

    def publish_twist(self, velocity):
        """Publish a velocity command."""
        msg = TwistStamped()
        msg.header.frame_id = ARM_FRAME
        v = msg.twist.linear
        v.x, v.y, v.z = (float(x) for x in velocity)
        self.twist_pub.publish(msg)

    def publish_until(self, publish, value, condition):
        """Call publish(value) every few ms until `condition()` holds."""
        def publish_and_check():
            publish(value)
            return condition()
        return wait_for(publish_and_check, spin=lambda: self.client.spin(0.003))

    def position(self):
        """Return the newest measured tool position."""
        p = self.poses[-1].pose.position
        return np.array([p.x, p.y, p.z])

    def still(self, count=20):
        """Return whether the last `count` measured positions are the same."""
        return len(self.poses) >= count and all(
            np.array_equal(self.position(), (m.pose.position.x, m.pose.position.y,
                                             m.pose.position.z))
            for m in list(self.poses)[-count:])


@pytest.fixture
def start_arm(install_prefix):
    """Yield start(parameters) -> (stand-in bridge, arm process) on a domain of their own."""
    started = []

    def start(parameters):
        bridge = Bridge(next_domain_id())
        started.append((bridge, slave_process(install_prefix, bridge.domain_id, parameters)))
        return started[-1]

    yield start
    for bridge, arm in started:
        bridge.client.close()  # before the arm dies, as the driver tests do
        arm.kill()


def test_arm_holds_until_commanded_follows_servo_cp_stops_at_the_wall_and_senses_it(start_arm):
    bridge, _ = start_arm([('start_position', vector_parameter((0.0, 0.0, 0.1))),
                           ('box.stiffness', '0.0')])
    bridge.client.wait(lambda: bridge.wrenches and bridge.still()
                       and bridge.pose_pub.get_subscription_count())
    # No motion before the first command: at rest where it started, nothing sensed.
    np.testing.assert_array_equal(bridge.position(), [0.0, 0.0, 0.1])
    assert bridge.poses[-1].header.frame_id == ARM_FRAME
    assert bridge.wrenches[-1].header.frame_id == FT_FRAME
    force = bridge.wrenches[-1].wrench.force
    assert (force.x, force.y, force.z) == (0.0, 0.0, 0.0)

    # A target 8 cm into the default floor at z = -0.04.
    target = (0.02, 0.04, -0.12)
    bridge.publish_until(bridge.publish_pose, target, lambda: (
        np.linalg.norm(bridge.position()[:2] - [0.02, 0.04]) < 1e-4))
    # Pressing with all it has (mass * max_acceleration = 5 N) and at rest where the wall's
    # spring alone holds it. The sensor, a quarter turn about z with the tool, reads the
    # wall's push on the tool in the tool's frame: +z stays +z.
    pressed = 5.0 / 20000.0
    bridge.publish_until(bridge.publish_pose, target, lambda: (
        abs(bridge.wrenches[-1].wrench.force.z - 5.0) < 1e-3
        and abs(-0.04 - bridge.position()[2] - pressed) < 0.01 * pressed))
    orientation = bridge.poses[-1].pose.orientation
    assert (orientation.z, orientation.w) == pytest.approx((math.sqrt(0.5),) * 2)


def test_arm_in_twist_mode_moves_while_commanded_and_holds_after(start_arm):
    bridge, _ = start_arm([('mode', 'twist'), ('box.stiffness', '0.0'),
                           ('wall.stiffness', '0.0')])
    bridge.client.wait(lambda: bridge.poses and bridge.twist_pub.get_subscription_count())
    np.testing.assert_array_equal(bridge.position(), np.zeros(3))
    bridge.publish_until(bridge.publish_twist, (0.0, 0.1, 0.0),
                         lambda: bridge.position()[1] > 0.05)
    # The command goes stale after command_timeout: the arm holds where it is.
    bridge.client.wait(bridge.still)
    position = bridge.position()
    assert position[1] > 0.05
    np.testing.assert_allclose(position[[0, 2]], 0.0, atol=1e-12)


def test_a_command_in_a_wrong_frame_is_refused_in_one_line_and_the_arm_holds(start_arm):
    # A long timeout: only the refusal can stop the arm following its last good command.
    bridge, arm = start_arm([('box.stiffness', '0.0'), ('command_timeout', '10.0')])
    bridge.client.wait(lambda: bridge.poses and bridge.pose_pub.get_subscription_count())
    target = (0.0, 0.0, 0.5)
    bridge.publish_until(bridge.publish_pose, target, lambda: bridge.position()[2] > 0.05)
    bridge.publish_until(lambda value: bridge.publish_pose(value, frame_id='world'), target,
                         bridge.still)
    assert bridge.position()[2] < 0.15
    code, output = arm.interrupt(signal.SIGINT)
    assert code == 0, output
    refusals = [line for line in output.splitlines() if 'servo_cp refused' in line]
    assert refusals and "frame_id 'world' is not arm_frame 'base_link'" in refusals[0]


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_signal_stops_the_node_with_exit_code_0(start_arm, sig):
    bridge, arm = start_arm([])
    bridge.client.wait(lambda: bridge.wrenches)
    code, output = arm.interrupt(sig)
    assert code == 0, output


@pytest.mark.parametrize('name, value, fragment', [
    ('mode', 'sideways', 'mode'),
    ('wall.normal', '[0.0, 0.0, 0.0]', 'wall.normal'),
    ('max_velocity', '-1.0', 'max_velocity'),
    ('start_position', '[1.0, 2.0]', 'position'),
    ('rate_hz', 'fast', 'rate_hz'),
])
def test_bad_parameter_exits_1_naming_it(install_prefix, name, value, fragment):
    arm = slave_process(install_prefix, next_domain_id(), [(name, value)])
    code, output = arm.wait_exit()
    assert code == 1, output
    assert fragment in output
