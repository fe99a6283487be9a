# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Teleoperation end to end: simulated device, installed driver, bridge and simulated arm.

The simulated hand controller runs in this process behind a real pseudo-terminal; the driver,
the bridge (kraft_master_teleop) and the simulated arm (kraft_master_slave_sim) are separate
processes talking over DDS. The arm starts where the master's wrist rests (home), the bridge
enables itself there, and the arm then follows the master's wrist one to one; its stiff wall
is placed across the directions in which the operator's hand, replayed from here once the
bridge is enabled, pushes the master.
"""
import collections
import math
import threading
import time

from geometry_msgs.msg import PoseStamped, WrenchStamped
from harness import dds_shm
from harness.driver import (
    DriverProcess, next_domain_id, RosClient, slave_process, vector_parameter, wait_for,
    WAIT_S)
from kraft_master_driver.core import kinematics
from kraft_master_driver.nodes.slave_sim import PARAMETERS
from kraft_master_driver.simulation.arms.point_mass import SlaveLimits
from kraft_master_driver.simulation.master.model import joints_to_actuators, Workspace
from kraft_master_driver.simulation.master.operators import SweepOperator
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

pytestmark = pytest.mark.integration

ARM = 'right'
BASE = 'kraft_master_base'
LOOP_RATE_HZ = 200.0
FORCE_SCALE = 0.1  # keeps the torques of impacts below the driver's torque_limits (2 N*m)
SWEEP_PERIOD = 2.0  # s per joint of the simulated operator's sweep
HOME_THETA = Workspace().home()
HOME = kinematics.forward(HOME_THETA, ARM)[:3, 3]
# At home, th1 moves the wrist mostly along +y and th2, th3 along +z: a wall across (0, 1, 1)
# is pushed into by the first half of each of their sweeps.
NORMAL = -np.array([0.0, 1.0, 1.0]) / math.sqrt(2.0)
WALL_STIFFNESS = PARAMETERS['wall.stiffness'][0]
LIMITS = SlaveLimits()
PENETRATION_TOLERANCE = 0.003  # m
# The client takes messages for this long between two checks of a condition (s): checked after
# every message, a condition that passes over thousands of them kept the client so far behind,
# with a busy loop per core, that fewer than 10 of the joint states it kept were one loop
# period apart.
CHECK_PERIOD_S = 0.02
TORQUE_RESOLUTION = 1.5e-3  # N*m: the device's 1 mN*m counts, on th2 the sum of two
# The bridge: enabled as soon as it can be (the master then rests at home), the point-mass
# arm's orientation kept, impacts reflected unlimited by it (the driver's force_scale keeps
# the torques low), timeouts a loaded machine's stalls do not trip, and a tracking limit the
# wall does not (it holds the arm short of its command, as deep as the master goes).
BRIDGE = [('enable_at_start', 'true'), ('orientation', 'fixed'), ('max_force', '200.0'),
          ('master_timeout', '2.0'), ('arm_timeout', '2.0'), ('ft_timeout', '2.0'),
          ('max_tracking_error', '1.0')]


def actuator_target(offset):
    """Return the actuator coordinates with the wrist at HOME + offset (shoulder, elbow)."""
    theta = HOME_THETA.copy()
    for _ in range(20):
        pose, jacobian = kinematics.forward_and_jacobian(theta, ARM)
        theta[:3] += np.linalg.lstsq(jacobian[:3, :3], HOME + offset - pose[:3, 3],
                                     rcond=None)[0]
    return joints_to_actuators(theta)


def depth(points, wall_point):
    """Return how deep (m) points (N, 3) are behind the wall; negative in free space."""
    return (wall_point - np.asarray(points)) @ NORMAL


def xyz(vector):
    """Return a geometry_msgs Point or Vector3 as an array."""
    return np.array([vector.x, vector.y, vector.z])


def seconds(stamp):
    """Return a header stamp in seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


class Teleoperation:
    """The simulated device here; driver, bridge and arm as processes; a client recording all."""

    def __init__(self, prefix, home_depth):
        """Start everything with the wall `home_depth` m in front of home (< 0)."""
        self.wall_point = HOME + home_depth * NORMAL
        self.domain_id = domain_id = next_domain_id()
        # The hand holds the master at home until the bridge is enabled; then operate() moves it.
        self.simulator = SimulatedKraftMaster(arm=ARM, operator='hold')
        port = self.simulator.start()
        self.driver = DriverProcess(prefix, domain_id, [
            ('port', port), ('arm', ARM), ('force_enabled_at_start', 'true'),
            ('loop_rate_hz', LOOP_RATE_HZ), ('force_scale', FORCE_SCALE)])
        self.bridge = DriverProcess(prefix, domain_id, BRIDGE, name='kraft_master_teleop')
        self.slave = slave_process(prefix, domain_id, [
            ('start_position', vector_parameter(HOME)), ('box.stiffness', '0.0'),
            ('wall.point', vector_parameter(self.wall_point)),
            ('wall.normal', vector_parameter(NORMAL))])
        self.client = RosClient(domain_id, history=5000)
        # Sampled from the start: the client may take seconds to discover the slave (a missed
        # DDS announcement waits for the next one), and the operator does not wait for it.
        self.true_master_depths = []
        self._sampling = threading.Event()
        self._sampler = threading.Thread(target=self._sample_true_depths, daemon=True)
        self._sampler.start()
        # Best effort: a reliable reader that misses the first samples while discovery
        # completes holds every later one back until the writer's next heartbeat (3 s in Fast
        # DDS), longer than some of these tests run.
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.wrenches = collections.deque(maxlen=5000)
        self.slave_poses = collections.deque(maxlen=5000)
        self.readings = collections.deque(maxlen=5000)
        self.states = []
        node = self.client.node
        node.create_subscription(
            WrenchStamped, 'wrench', lambda msg: self.wrenches.append(msg), qos)
        node.create_subscription(
            PoseStamped, 'measured_cp', lambda msg: self.slave_poses.append(msg), qos)
        node.create_subscription(
            WrenchStamped, 'measured_cf', lambda msg: self.readings.append(msg), qos)
        node.create_subscription(
            String, 'operating_state', lambda msg: self.states.append(msg.data),
            QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self._operating = threading.Event()
        self._operator = None
        try:
            self.client.wait(lambda: self.client.joint_states and self.slave_poses
                             and self.states and self.states[-1] == 'ENABLED')
        except AssertionError:
            outputs = []
            for started in (self.driver, self.bridge, self.slave):
                dds_shm.end(started.process)
                outputs.append(started.process.communicate(timeout=10)[0])
            self.close()
            raise AssertionError('driver, bridge or arm did not start, or the bridge was not '
                                 'enabled:\n' + '\n'.join(outputs))

    def operate(self, target):
        """Move the operator's hand to the actuator coordinates `target(t)` from now on."""
        def run():
            started = time.monotonic()
            while not self._operating.wait(0.005):
                self.simulator.hold_at(target(time.monotonic() - started))
        self._operator = threading.Thread(target=run, daemon=True)
        self._operator.start()

    def _sample_true_depths(self):
        """Record the device's true wrist depth every 2 ms until close()."""
        while not self._sampling.wait(0.002):
            theta = self.simulator.joint_angles()
            self.true_master_depths.append(
                depth(kinematics.forward(theta, ARM)[:3, 3], self.wall_point))

    def wait(self, condition, timeout=WAIT_S):
        """Spin until `condition()` holds, checking it every CHECK_PERIOD_S."""
        return wait_for(condition, timeout, spin=lambda: self.client.spin(CHECK_PERIOD_S))

    def assert_alone(self):
        """Fail clearly if another test's nodes share this DDS domain (they would mix in)."""
        node = self.client.node
        publishers = {topic: node.count_publishers(topic)
                      for topic in ('pose', 'joint_states', 'measured_cp', 'wrench')}
        assert publishers == {'pose': 1, 'joint_states': 1, 'measured_cp': 1, 'wrench': 1}, (
            f'publishers on domain {self.domain_id}: {publishers}')

    def master_depths(self):
        """Return the depth behind the wall of the master's wrist for each joint state."""
        positions = np.array([s.position for s in self.client.joint_states])
        return depth(kinematics.forward(positions, ARM)[:, :3, 3], self.wall_point)

    def slave_depths(self):
        """Return the depth behind the wall of each recorded slave pose."""
        return depth([xyz(p.pose.position) for p in self.slave_poses], self.wall_point)

    def forces(self):
        """Return the recorded wrench forces, an (N, 3) array in the master's base frame."""
        return np.array([xyz(w.wrench.force) for w in self.wrenches])

    def device_torque(self):
        """Return the torque counts of the newest command the device received."""
        return self.simulator.received[-1][1].counts

    def close(self):
        """Stop everything, whatever state the test left it in."""
        self._sampling.set()
        self._sampler.join()
        self._operating.set()
        if self._operator is not None:
            self._operator.join()
        self.client.close()
        self.slave.kill()
        self.bridge.kill()
        self.driver.kill()
        self.simulator.stop()


@pytest.fixture
def sweeping(install_prefix):
    """Yield a session: the operator sweeps each joint in turn, the wall 15 mm from home."""
    running = Teleoperation(install_prefix, home_depth=-0.015)
    running.operate(SweepOperator(Workspace(), SWEEP_PERIOD).target)
    yield running
    running.close()


@pytest.fixture
def pressing(install_prefix):
    """Yield a session: the operator holds the master 10 mm behind the wall, 5 mm from home."""
    running = Teleoperation(install_prefix, home_depth=-0.005)
    behind = actuator_target(-0.015 * NORMAL)
    running.operate(lambda _t: behind)
    yield running
    running.close()


def implied_force(jacobian, effort):
    """Return the pure force F (3,) with effort = J^T (F, 0) on th1..th5 (least squares)."""
    return np.linalg.lstsq(jacobian[:3, :5].T, np.asarray(effort)[:5], rcond=None)[0]


def contact_states(client):
    """Return the recorded joint states with a commanded torque, each with the one before."""
    states = list(client.joint_states)
    return [(previous, state) for previous, state in zip(states, states[1:])
            if any(state.effort)]


def test_slave_stops_at_the_wall_and_the_master_is_pushed_back(sweeping):
    client = sweeping.client
    # Contacts until the master has felt the wall for a while and the client has seen the
    # slave at the wall, then a release.
    sweeping.wait(lambda: len(contact_states(client)) >= 20 and sweeping.slave_poses
                  and sweeping.slave_depths().max() > 0.0, timeout=40.0)
    sweeping.wait(lambda: sweeping.master_depths()[-1] < 0.0
                  and not np.any(sweeping.forces()[-1]))

    sweeping.assert_alone()
    slave_depths, master_depth = sweeping.slave_depths(), max(sweeping.true_master_depths)
    print(f'deepest: master {1e3 * master_depth:.1f} mm, slave {1e3 * slave_depths.max():.2f} mm')
    assert master_depth > 0.02, 'the operator pushed the master through the wall'
    assert 0.0 < slave_depths.max() < PENETRATION_TOLERANCE

    # The wrench: in the base frame, a pure force along the wall's normal, never pulling.
    assert {w.header.frame_id for w in sweeping.wrenches} == {BASE}
    assert not any(np.any(xyz(w.wrench.torque)) for w in sweeping.wrenches)
    forces = sweeping.forces()
    along = forces @ NORMAL
    assert along.min() >= 0.0 and along.max() > 1.0
    np.testing.assert_allclose(forces, np.outer(along, NORMAL), atol=1e-9)
    # The arm's sensor reads nothing out of contact (its pose and reading share a stamp).
    by_stamp = {(w.header.stamp.sec, w.header.stamp.nanosec): xyz(w.wrench.force)
                for w in sweeping.readings}
    paired = 0
    for pose, slave_depth in zip(sweeping.slave_poses, slave_depths):
        force = by_stamp.get((pose.header.stamp.sec, pose.header.stamp.nanosec))
        if force is not None and slave_depth <= 0.0:
            assert not np.any(force), 'a force out of contact'
            paired += 1
    assert paired >= 10

    # The master's torques are J^T (force_scale F, 0) for a force F out of the wall: the
    # driver computed them with the Jacobian of the sample before, so only pairs one loop
    # period apart are checked (at idle, the client kept pairs 45 to 60 ms apart, the master
    # having turned up to 0.23 rad between them). Torques of a few counts say little about a
    # direction. (Their magnitude is checked while pressing, below: here the client may miss
    # the wrench the driver used.)
    checked = 0
    for previous, state in contact_states(client):
        if (np.abs(state.effort).max() < 20 * TORQUE_RESOLUTION
                or seconds(state.header.stamp) - seconds(previous.header.stamp)
                > 1.5 / LOOP_RATE_HZ):
            continue
        force = implied_force(kinematics.jacobian(previous.position, ARM), state.effort)
        pair = (f'states {seconds(state.header.stamp) - seconds(previous.header.stamp):.4f} s '
                f'apart, {np.abs(np.subtract(state.position, previous.position)).max():.4f} rad '
                f'apart at most, effort {list(state.effort)}')
        assert force @ NORMAL > 0.0, f'the torques must push the wrist out of the wall; {pair}'
        assert np.linalg.norm(np.cross(force, NORMAL)) < 0.05 * np.linalg.norm(force) + 0.01, (
            f'the torques imply {force.tolist()}, not along the normal; {pair}')
        checked += 1
    assert checked >= 10


def test_pressing_on_the_wall_then_zero_torque_when_the_arm_dies(pressing):
    client = pressing.client
    # The slave pushes with all it has, mass * max_acceleration, and the wall holds it. A stall
    # of the master's poses longer than the arm's command_timeout (a loaded machine has them)
    # makes the arm hold where it is: steady too, but short of the full push, until the poses
    # come again. So the test waits for 25 readings in a row at the full push.
    push = LIMITS.mass * LIMITS.max_acceleration * NORMAL

    def pushing_fully():
        forces = pressing.forces()[-25:]
        return len(forces) == 25 and np.abs(forces - push).max() < 1e-6

    try:
        pressing.wait(pushing_fully)
    except AssertionError:
        raise AssertionError(f'no 25 forces in a row at the full push {push}; the last: '
                             f'{pressing.forces()[-25:].tolist()}') from None
    pressing.assert_alone()
    force = pressing.forces()[-1]
    slave_depth = pressing.slave_depths()[-1]
    assert slave_depth == pytest.approx(np.linalg.norm(force) / WALL_STIFFNESS, rel=1e-3)
    print(f'pressing: slave {1e3 * slave_depth:.3f} mm deep, master '
          f'{1e3 * pressing.master_depths()[-1]:.1f} mm deep')

    client.wait(lambda: any(client.joint_states[-1].effort))
    state = client.joint_states[-1]
    expected = kinematics.jacobian(state.position, ARM).T @ np.concatenate(
        [FORCE_SCALE * force, np.zeros(3)])
    np.testing.assert_allclose(state.effort[:5], expected[:5], atol=TORQUE_RESOLUTION)
    assert np.abs(expected).max() > 0.05
    client.wait(lambda: any(pressing.device_torque()))

    # The arm's pose and reading go stale: the bridge faults and sends the master zero.
    pressing.slave.kill()
    client.wait(lambda: not any(pressing.device_torque())
                and not any(client.joint_states[-1].effort))
    assert pressing.master_depths()[-1] > 0.0, 'still behind the wall: only the bridge acted'
    # Both of the arm's streams stop: whichever the bridge finds stale first names the fault
    # (killed between its pose and its reading, the arm leaves the reading the older).
    stale = ('FAULT: measured_cp older', 'FAULT: measured_cf older')
    client.wait(lambda: pressing.states[-1].startswith(stale))
