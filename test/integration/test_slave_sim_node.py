# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The installed simulated slave on its own, fed by a stand-in for the driver's topics."""
import collections
import math
import signal

from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from harness.driver import next_domain_id, RosClient, slave_process, vector_parameter, wait_for
import numpy as np
import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy


class Master:
    """A stand-in for the driver's topics: publishes pose or rate_command, records the rest."""

    def __init__(self, domain_id):
        """Join the domain; record wrench and slave_pose."""
        self.domain_id = domain_id
        self.client = RosClient(domain_id)
        node = self.client.node
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.wrenches = collections.deque(maxlen=2000)
        self.slave_poses = collections.deque(maxlen=2000)
        node.create_subscription(
            WrenchStamped, 'wrench', lambda msg: self.wrenches.append(msg), qos)
        node.create_subscription(
            PoseStamped, 'slave_pose', lambda msg: self.slave_poses.append(msg), qos)
        self.pose_pub = node.create_publisher(PoseStamped, 'pose', qos)
        self.rate_pub = node.create_publisher(TwistStamped, 'rate_command', qos)

    def publish_pose(self, position):
        """Publish a master wrist pose at `position`, orientation a quarter turn about z."""
        msg = PoseStamped()
        msg.header.frame_id = 'kraft_master_base'
        p, q = msg.pose.position, msg.pose.orientation
        p.x, p.y, p.z = (float(v) for v in position)
        q.z = q.w = math.sqrt(0.5)
        self.pose_pub.publish(msg)

    def publish_rate(self, velocity):
        """Publish a rate command."""
        msg = TwistStamped()
        v = msg.twist.linear
        v.x, v.y, v.z = (float(x) for x in velocity)
        self.rate_pub.publish(msg)

    def publish_until(self, publish, value, condition):
        """Call publish(value) every few ms until `condition()` holds."""
        def publish_and_check():
            publish(value)
            return condition()
        return wait_for(publish_and_check, spin=lambda: self.client.spin(0.003))

    def slave_position(self):
        """Return the newest slave position, or None."""
        if not self.slave_poses:
            return None
        p = self.slave_poses[-1].pose.position
        return np.array([p.x, p.y, p.z])


@pytest.fixture
def start_slave(install_prefix):
    """Yield start(parameters) -> (stand-in master, slave process) on a domain of their own."""
    started = []

    def start(parameters):
        master = Master(next_domain_id())
        started.append((master, slave_process(install_prefix, master.domain_id, parameters)))
        return started[-1]

    yield start
    for master, slave in started:
        master.client.close()  # before the slave dies, as the driver tests do
        slave.kill()


def test_node_follows_the_pose_stops_at_the_wall_and_reflects_the_force(start_slave):
    master, _ = start_slave([
        ('centre', '[0.0, 0.0, 0.0]'), ('offset', vector_parameter((0.0, 0.0, 0.1))),
        ('box.stiffness', '0.0'), ('scale', '2.0')])
    master.client.wait(lambda: master.wrenches and master.pose_pub.get_subscription_count())
    assert not master.slave_poses, 'no slave pose before the first master pose'
    force = master.wrenches[-1].wrench.force
    assert (force.x, force.y, force.z) == (0.0, 0.0, 0.0)
    assert master.wrenches[-1].header.frame_id == 'kraft_master_base'

    # Slave target = offset + 2 * master: 10 cm into the default floor at z = -0.04.
    target = (0.01, 0.02, -0.12)
    master.publish_until(master.publish_pose, target, lambda: (
        master.slave_position() is not None and
        np.linalg.norm(master.slave_position()[:2] - [0.02, 0.04]) < 1e-4))
    # Pressing with all it has (mass * max_acceleration = 5 N), reflected times the scale, and at
    # rest where the wall's spring alone holds it (moving in, the wall's damping adds force).
    pressed = 5.0 / 20000.0
    master.publish_until(master.publish_pose, target, lambda: (
        abs(master.wrenches[-1].wrench.force.z - 2.0 * 5.0) < 1e-3
        and abs(-0.04 - master.slave_position()[2] - pressed) < 0.01 * pressed))
    orientation = master.slave_poses[-1].pose.orientation
    assert (orientation.z, orientation.w) == pytest.approx((math.sqrt(0.5),) * 2)


def test_node_in_rate_mode_moves_while_commanded_and_stops_after(start_slave):
    master, _ = start_slave([('mode', 'rate'), ('box.stiffness', '0.0'),
                             ('wall.stiffness', '0.0')])
    master.client.wait(lambda: master.slave_poses and master.rate_pub.get_subscription_count())
    np.testing.assert_array_equal(master.slave_position(), np.zeros(3))
    master.publish_until(master.publish_rate, (0.0, 0.1, 0.0),
                         lambda: master.slave_position()[1] > 0.05)
    # The command goes stale after command_timeout: the slave stops where it is.
    master.client.wait(lambda: abs(master.slave_poses[-1].pose.position.y -
                                   master.slave_poses[-20].pose.position.y) < 1e-9)
    position = master.slave_position()
    assert position[1] > 0.05
    np.testing.assert_allclose(position[[0, 2]], 0.0, atol=1e-12)


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_signal_stops_the_node_with_exit_code_0(start_slave, sig):
    master, slave = start_slave([])
    master.client.wait(lambda: master.wrenches)
    code, output = slave.interrupt(sig)
    assert code == 0, output


@pytest.mark.parametrize('name, value, fragment', [
    ('mode', 'sideways', 'mode'),
    ('wall.normal', '[0.0, 0.0, 0.0]', 'wall.normal'),
    ('max_velocity', '-1.0', 'max_velocity'),
    ('offset', '[1.0, 2.0]', 'offset'),
    ('rate_hz', 'fast', 'rate_hz'),
])
def test_bad_parameter_exits_1_naming_it(install_prefix, name, value, fragment):
    slave = slave_process(install_prefix, next_domain_id(), [(name, value)])
    code, output = slave.wait_exit()
    assert code == 1, output
    assert fragment in output
