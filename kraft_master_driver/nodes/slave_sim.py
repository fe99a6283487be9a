# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_slave_sim: a simulated slave arm for topic-based teleoperation with the driver.

The slave is a point mass (its Cartesian wrist point) servoed toward a target with velocity
and acceleration limits, in an environment with a stiff virtual wall and a soft box. In
'position' mode it follows the master's `pose` (target = offset + scale * (master position -
centre), orientation copied; the centre is fixed, by default the middle of the master's
workspace, so that a master pose always gives the same target); in 'rate' mode it moves at
scale * `rate_command`. Every cycle it publishes `slave_pose` and, on the master's `wrench`
topic, the contact force mapped back to the master (scale * force, in the master's base frame;
zero out of contact), which also keeps the driver's wrench watchdog fed while the slave lives.

SlaveArm, Wall, SoftBox and MasterSlaveMap are plain Python (no ROS) and unit-tested; the node
below them only moves messages.
"""
import math
import sys
import threading
import time
from typing import NamedTuple

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TwistStamped, Vector3Stamped, WrenchStamped
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.passivity import LinkMonitor, SlavePort
from kraft_master_driver.link import cdr
from kraft_master_driver.nodes.lifecycle import run_node
from kraft_master_driver.nodes.parameters import (
    declare_parameters, ParameterError, Spec)
from kraft_master_driver.nodes.ros_helpers import steady_timer, TakenByLoopThread
from kraft_master_driver.simulation.model import Workspace
import numpy as np
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

MODES = ('position', 'rate')
MAX_STEP = 0.002  # s, longest integration step
MAX_CATCH_UP = 0.1  # s of simulated time per advance(); a longer stall is skipped, not replayed
TICK_QUEUE = 10  # messages a topic taken by the ticks holds between two ticks


def _vector(name, values):
    """Return `values` as a float array of 3 finite numbers, else raise ValueError."""
    try:
        array = np.array(values, dtype=float)
    except (TypeError, ValueError):
        array = None
    if array is None or array.shape != (3,) or not np.all(np.isfinite(array)):
        raise ValueError(f'{name} must be 3 finite numbers, got {values!r}')
    return array


def _number(name, value, positive=False):
    """Return `value` as a finite float >= 0 (> 0 if positive), else raise ValueError."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f'{name} must be a number, got {value!r}')
    if not (math.isfinite(value) and (value > 0.0 if positive else value >= 0.0)):
        raise ValueError(f'{name} must be finite and {">" if positive else ">="} 0, got {value}')
    return float(value)


def _push(normal, depth, velocity, stiffness, damping):
    """Spring-damper force (N) along a unit `normal` at `depth` (m), never pulling."""
    rate = -float(velocity @ normal)
    return max(stiffness * depth + damping * rate, 0.0) * normal


def _clamp_norm(vector, limit):
    """Return `vector` shortened to length `limit` if it is longer."""
    length = math.sqrt(float(vector @ vector))
    return vector * (limit / length) if length > limit else vector


class Wall:
    """A stiff plane through `point`; free space lies on the side `normal` points to."""

    def __init__(self, point, normal, stiffness, damping):
        """Check the plane (m), stiffness (N/m) and damping (N*s/m); the normal is normalised."""
        self.point = _vector('wall.point', point)
        normal = _vector('wall.normal', normal)
        length = math.sqrt(float(normal @ normal))
        if length == 0.0:
            raise ValueError('wall.normal must not be zero')
        self.normal = normal / length
        self.stiffness = _number('wall.stiffness', stiffness)
        self.damping = _number('wall.damping', damping)

    def penetration(self, position):
        """Return how deep (m) `position` is behind the surface; negative in free space."""
        return float((self.point - position) @ self.normal)

    def force(self, position, velocity):
        """Force (N) on a point: k * depth + b * depth rate along the normal, never pulling."""
        depth = self.penetration(position)
        if depth <= 0.0:
            return np.zeros(3)
        return _push(self.normal, depth, velocity, self.stiffness, self.damping)


class SoftBox:
    """A soft box: a point inside is pushed out through the nearest face, like the wall's."""

    def __init__(self, centre, half_sizes, stiffness, damping):
        """Check the centre (m), half sizes (m, > 0), stiffness (N/m) and damping (N*s/m)."""
        self.centre = _vector('box.centre', centre)
        self.half_sizes = _vector('box.half_sizes', half_sizes)
        if not np.all(self.half_sizes > 0.0):
            raise ValueError(f'box.half_sizes must be > 0, got {self.half_sizes.tolist()}')
        self.stiffness = _number('box.stiffness', stiffness)
        self.damping = _number('box.damping', damping)

    def force(self, position, velocity):
        """Force (N) on a point at `position` moving at `velocity`; zero outside the box."""
        offset = position - self.centre
        depth = self.half_sizes - np.abs(offset)
        if not np.all(depth > 0.0):
            return np.zeros(3)
        axis = int(np.argmin(depth))
        normal = np.zeros(3)
        normal[axis] = math.copysign(1.0, offset[axis])
        return _push(normal, float(depth[axis]), velocity, self.stiffness, self.damping)


class SlaveLimits(NamedTuple):
    """The slave's servo: limits (m/s, m/s^2), moving mass (kg) and loop gains (1/s)."""

    max_velocity: float = 0.25  # ISO 10218-1's reduced speed for manual mode
    max_acceleration: float = 5.0  # with the mass, the largest force the slave can push with
    mass: float = 1.0
    position_gain: float = 15.0
    velocity_gain: float = 60.0  # 4 * position_gain: the cascade is critically damped

    def checked(self):
        """Return the limits with every value a positive finite float, else raise ValueError."""
        return SlaveLimits(*(_number(name, value, positive=True)
                             for name, value in zip(self._fields, self)))


class SlaveArm:
    """
    The slave's wrist point: a mass driven by a velocity-limited, force-limited servo.

    Each step the servo asks for a desired velocity (clamped to max_velocity), its
    acceleration toward it is clamped to max_acceleration, and the environment's contact force
    acts on the mass on top of it: in steady contact the slave pushes with at most
    mass * max_acceleration, and an obstacle stops it whatever its target.
    """

    def __init__(self, limits=SlaveLimits(), wall=None, box=None):
        """Set up a slave with no position yet: call reset() first."""
        self.limits = limits.checked()
        self.wall = wall
        self.box = box
        self.position = None
        self.velocity = np.zeros(3)

    def reset(self, position):
        """Put the slave at rest at `position` (m), or on the wall's surface if behind it."""
        position = _vector('position', position)
        if self.wall is not None:
            position += max(self.wall.penetration(position), 0.0) * self.wall.normal
        self.position = position
        self.velocity = np.zeros(3)

    def contact_force(self):
        """Return the environment's force (N) on the slave now."""
        force = np.zeros(3)
        if self.wall is not None:
            force += self.wall.force(self.position, self.velocity)
        if self.box is not None:
            force += self.box.force(self.position, self.velocity)
        return force

    def step(self, dt, desired_velocity):
        """Advance `dt` seconds (semi-implicit Euler) with the servo asking `desired_velocity`."""
        limits = self.limits
        wanted = _clamp_norm(np.asarray(desired_velocity, dtype=float), limits.max_velocity)
        drive = _clamp_norm(limits.velocity_gain * (wanted - self.velocity),
                            limits.max_acceleration)
        self.velocity = self.velocity + dt * (drive + self.contact_force() / limits.mass)
        self.position = self.position + dt * self.velocity

    def advance(self, elapsed, target=None, velocity=None):
        """
        Run `elapsed` s in steps of at most MAX_STEP; return the contact force (N) at the end.

        Give `target` (m) to servo toward a position, or `velocity` (m/s) to move at a rate.
        """
        elapsed = min(elapsed, MAX_CATCH_UP)
        steps = max(1, math.ceil(elapsed / MAX_STEP))
        dt = elapsed / steps
        for _ in range(steps):
            desired = (velocity if target is None
                       else self.limits.position_gain * (target - self.position))
            self.step(dt, desired)
        return self.contact_force()


class MasterSlaveMap:
    """
    Master wrist -> slave target: offset + scale * (position - centre), axes aligned.

    Forces go back through the transpose of the same map, scale * force, so the power the
    master feels equals the power the slave exchanges with its environment. With centre None
    the first master position becomes the centre.
    """

    def __init__(self, scale=1.0, offset=(0.0, 0.0, 0.0), centre=None):
        """Check scale (> 0), offset (m) and centre (m, or None)."""
        self.scale = _number('scale', scale, positive=True)
        self.offset = _vector('offset', offset)
        self.centre = None if centre is None else _vector('centre', centre)

    def target(self, master_position):
        """Return where the slave should be (m) when the master's wrist is at master_position."""
        master_position = _vector('master position', master_position)
        if self.centre is None:
            self.centre = master_position
        return self.offset + self.scale * (master_position - self.centre)

    def velocity(self, master_velocity):
        """Return the slave's rate in m/s for the master's rate command in m/s."""
        return self.scale * np.asarray(master_velocity, dtype=float)

    def reflect(self, slave_force):
        """Return the force (N) for the master of a force (N) acting on the slave."""
        return self.scale * np.asarray(slave_force, dtype=float)


def integrate_quaternion(quaternion, angular_velocity, dt):
    """Turn a unit quaternion (x, y, z, w) by angular_velocity (rad/s, base frame) for dt s."""
    rotation = np.asarray(angular_velocity, dtype=float) * dt
    angle = math.sqrt(float(rotation @ rotation))
    if angle == 0.0:
        return tuple(quaternion)
    ux, uy, uz = rotation * (math.sin(angle / 2.0) / angle)
    uw = math.cos(angle / 2.0)
    x, y, z, w = quaternion
    turned = np.array([
        uw * x + ux * w + uy * z - uz * y,
        uw * y - ux * z + uy * w + uz * x,
        uw * z + ux * y - uy * x + uz * w,
        uw * w - ux * x - uy * y - uz * z,
    ])
    return tuple((turned / math.sqrt(float(turned @ turned))).tolist())


# -- the node ---------------------------------------------------------------------------

POSE_STAMPED = cdr.StampedDoublesDecoder('PoseStamped', 7)
TWIST_STAMPED = cdr.StampedDoublesDecoder('TwistStamped', 6)
VECTOR3_STAMPED = cdr.StampedDoublesDecoder('Vector3Stamped', 3)


def master_centre(arm):
    """Return the master's wrist position (m, 3 floats) in the middle of the arm's workspace."""
    return kinematics.forward(Workspace().home(), arm)[:3, 3].tolist()


def _parameter_table(node):
    """PARAMETERS with the default centre of the arm given to `node` (right if none is)."""
    given = node._parameter_overrides.get('arm')  # no public accessor in rclpy
    arm = given.value if given is not None and given.value in kinematics.ARMS else 'right'
    return dict(PARAMETERS, centre=PARAMETERS['centre']._replace(default=master_centre(arm)))


_DEFAULT_LIMITS = SlaveLimits()

PARAMETERS = {
    'mode': Spec('position', "'position': follow the master's pose; 'rate': its rate_command."),
    'rate_hz': Spec(500.0, 'Simulation and publishing rate (Hz).'),
    'scale': Spec(1.0, 'Slave motion per master motion (1); the reflected force is scale '
                  'times the force on the slave.'),
    'offset': Spec([0.0, 0.0, 0.0], 'Slave position when the master is at the centre (m).'),
    'arm': Spec('right', "The master's arm, right or left: the default centre lies in its "
                'workspace.', choices=kinematics.ARMS),
    'centre_at_start': Spec(False, "The master's first pose the slave hears is the centre (it "
                            'then depends on when the slave starts); else centre.'),
    'centre': Spec(master_centre('right'), 'Master wrist position mapped to offset (m), base '
                   "frame; default: the middle of the arm's workspace, where the simulated "
                   "operator's hand rests (shown for the right arm)."),
    'command_timeout': Spec(0.1, 'Rate mode: an older rate_command stops the slave (s).'),
    'max_velocity': Spec(_DEFAULT_LIMITS.max_velocity, 'Slave speed limit (m/s).'),
    'max_acceleration': Spec(_DEFAULT_LIMITS.max_acceleration, 'Slave servo acceleration '
                             'limit (m/s^2); times mass, the largest force it pushes with.'),
    'mass': Spec(_DEFAULT_LIMITS.mass, 'Moving mass of the slave (kg).'),
    'position_gain': Spec(_DEFAULT_LIMITS.position_gain, 'Position loop gain (1/s).'),
    'velocity_gain': Spec(_DEFAULT_LIMITS.velocity_gain, 'Velocity loop gain (1/s).'),
    'wall.point': Spec([0.0, 0.0, -0.04], 'A point of the wall plane (m), slave frame.'),
    'wall.normal': Spec([0.0, 0.0, 1.0], 'Wall normal, pointing into free space.'),
    'wall.stiffness': Spec(20000.0, 'Wall stiffness (N/m); 0 removes the wall.'),
    'wall.damping': Spec(100.0, 'Wall damping (N*s/m).'),
    'box.centre': Spec([0.0, 0.12, 0.0], 'Centre of the soft box (m), slave frame.'),
    'box.half_sizes': Spec([0.1, 0.06, 0.04], 'Half sizes of the soft box along x, y, z (m).'),
    'box.stiffness': Spec(200.0, 'Soft box stiffness (N/m); 0 removes the box.'),
    'box.damping': Spec(20.0, 'Soft box damping (N*s/m).'),
    'base_frame': Spec('kraft_master_base', "frame_id of the wrench: the driver's base_frame."),
    'slave_frame': Spec('slave_world', 'frame_id of slave_pose.'),
    'passivity': Spec(False, "Position mode: time-domain passivity control of the master's "
                      'motion, fed by the master_energy topic; false: follow it as it comes.'),
    'drift_gain': Spec(2.0, 'Rate at which passivity drift is given back with spare energy '
                       '(1/s).', low=0.0, high=1000.0),
}


class SlaveSimNode(Node):
    """Runs a SlaveArm against the master's pose or rate command and reflects its contacts."""

    def __init__(self, params_files=(), **kwargs):
        """Declare and check the parameters, then start the fixed-rate simulation timer."""
        super().__init__('kraft_master_slave_sim', **kwargs)
        config = declare_parameters(self, _parameter_table(self), params_files)
        try:
            if config['mode'] not in MODES:
                raise ValueError(f'mode must be one of {", ".join(MODES)}, '
                                 f'got {config["mode"]!r}')
            rate_hz = _number('rate_hz', config['rate_hz'], positive=True)
            self.timeout = _number('command_timeout', config['command_timeout'], positive=True)
            self.map = MasterSlaveMap(
                config['scale'], config['offset'],
                None if config['centre_at_start'] else config['centre'])
            wall = Wall(config['wall.point'], config['wall.normal'], config['wall.stiffness'],
                        config['wall.damping'])
            box = SoftBox(config['box.centre'], config['box.half_sizes'],
                          config['box.stiffness'], config['box.damping'])
            self.arm = SlaveArm(SlaveLimits(*(config[name] for name in SlaveLimits._fields)),
                                wall if wall.stiffness > 0.0 else None,
                                box if box.stiffness > 0.0 else None)
        except ValueError as error:
            raise ParameterError(f'parameter {error}') from None
        self.port = SlavePort(_number('drift_gain', config['drift_gain']))
        self.port.enabled = bool(config['passivity'])
        self.pose_link = LinkMonitor()
        self.mode = config['mode']
        self.base_frame = config['base_frame']
        self.slave_frame = config['slave_frame']
        self.target = None
        self.orientation = (0.0, 0.0, 0.0, 1.0)
        self.rate = None  # (linear, angular, monotonic receipt time) of the last rate_command

        state_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.wrench_pub = self.create_publisher(WrenchStamped, 'wrench', state_qos)
        self.pose_pub = self.create_publisher(PoseStamped, 'slave_pose', state_qos)
        # The master's 1 kHz messages are taken raw by each tick, all that came since the last
        # (each one's delay counts; the newest wins), as the driver takes its wrenches: the
        # executor never wakes for them.
        self._wrench_cdr = cdr.StampedDoublesEncoder(self.base_frame, 6)
        self._pose_cdr = cdr.StampedDoublesEncoder(self.slave_frame, 7)
        msg_type, topic, on_message = (
            (PoseStamped, 'pose', self._on_pose) if self.mode == 'position'
            else (TwistStamped, 'rate_command', self._on_rate_command))
        self._command_sub = self._taken_by_ticks(msg_type, topic, on_message)
        # The slave port's energy in, out and dissipated (J), stamped as the wrench; the
        # master's, taken like its pose.
        self._energy_cdr = cdr.StampedDoublesEncoder(self.base_frame, 3)
        self.energy_pub = self.create_publisher(Vector3Stamped, 'slave_energy', state_qos)
        self._master_energy_sub = self._taken_by_ticks(
            Vector3Stamped, 'master_energy', self._on_master_energy)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', state_qos)
        steady_timer(self, 1.0, self._publish_diagnostics)
        if self.mode == 'rate':
            self.arm.reset(self.map.offset)
        self.last_tick = time.monotonic()
        # A thread of its own paces the ticks: with an executor's timer the process took about
        # twice the CPU (measured).
        self._period = 1.0 / rate_hz
        self._running = True
        self._thread = threading.Thread(target=self._run, name='slave_sim')
        self._thread.start()
        centre = self.map.centre
        self.get_logger().info(
            f'slave in {self.mode} mode at {rate_hz:g} Hz; wall '
            f'{"on" if self.arm.wall else "off"}, soft box {"on" if self.arm.box else "off"}'
            + ('' if self.mode == 'rate' else '; master centre ' + (
                'its first pose' if centre is None
                else '(' + ', '.join(f'{v:.4f}' for v in centre) + ') m')))

    def _taken_by_ticks(self, msg_type, topic, on_message):
        """Subscribe to `topic` for _take_all: raw, never run by the executor."""
        return self.create_subscription(
            msg_type, topic, on_message,
            # A few ticks' worth: a message the next overwrote would count as lost on the link.
            QoSProfile(depth=TICK_QUEUE, reliability=ReliabilityPolicy.BEST_EFFORT), raw=True,
            callback_group=TakenByLoopThread(),
            event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))

    def _take_all(self, subscription):
        """Hand each message that came (CDR bytes, oldest first), with its receipt time, on."""
        with subscription.handle:
            while (taken := subscription.handle.take_message(
                    subscription.msg_type, True)) is not None:
                # When DDS received it (system clock, ns), not when this tick got to it.
                received_ns = taken[1]['received_timestamp'] or time.time_ns()
                try:
                    subscription.callback(taken[0], received_ns)
                except ValueError as error:
                    self.get_logger().warning(f'{subscription.topic_name} ignored: {error}',
                                              throttle_duration_sec=1.0)

    def _on_master_energy(self, data, _received_ns):
        self.port.credit(VECTOR3_STAMPED.decode(data)[3][0])

    def _on_pose(self, data, received_ns):
        sec, nanosec, _, values = POSE_STAMPED.decode(data)
        self.pose_link.add(sec * 1_000_000_000 + nanosec, received_ns)
        self.target = self.map.target(values[:3])
        self.orientation = values[3:]
        if self.arm.position is None:
            self.arm.reset(self.target)

    def _on_rate_command(self, data, _received_ns):
        values = TWIST_STAMPED.decode(data)[3]
        self.rate = (self.map.velocity(values[:3]), np.array(values[3:]), time.monotonic())

    def _run(self):
        """Tick every period until destroy_node() or the end of the ROS context."""
        deadline = time.monotonic()
        while self._running and self.context.ok():
            deadline += self._period
            delay = deadline - time.monotonic()
            if delay > 0.0:
                time.sleep(delay)
            else:
                deadline -= delay  # late: the next tick a period from now, no burst
            try:
                self._tick()
            except Exception:  # noqa: B902 - publishing fails once a signal ends the context
                if self._running and self.context.ok():
                    raise
                return

    def destroy_node(self):
        """Stop the ticks, then the node."""
        self._running = False
        self._thread.join()
        super().destroy_node()

    def _tick(self):
        self._take_all(self._command_sub)
        self._take_all(self._master_energy_sub)
        now = time.monotonic()
        elapsed, self.last_tick = min(now - self.last_tick, MAX_CATCH_UP), now
        force = np.zeros(3)
        if self.mode == 'position' and self.target is not None:
            # What a real slave's bridge does: the master's motion goes through the passivity
            # controller, and the servo tracks the passive command instead of the target.
            command = self.port.step(self.target.tolist(), self.arm.contact_force().tolist(),
                                     elapsed)
            force = self.arm.advance(elapsed, target=np.array(command))
        elif self.mode == 'rate':
            linear = angular = np.zeros(3)
            if self.rate is not None and now - self.rate[2] <= self.timeout:
                linear, angular, _ = self.rate
            force = self.arm.advance(elapsed, velocity=linear)
            self.orientation = integrate_quaternion(self.orientation, angular, elapsed)
        sec, nanosec = divmod(self.get_clock().now().nanoseconds, 1_000_000_000)
        self.wrench_pub.publish(self._wrench_cdr.encode(
            sec, nanosec, self.map.reflect(force).tolist() + [0.0, 0.0, 0.0]))
        port = self.port
        self.energy_pub.publish(self._energy_cdr.encode(
            sec, nanosec, (port.energy_in, port.energy_out, port.dissipated)))
        if self.arm.position is not None:
            self.pose_pub.publish(self._pose_cdr.encode(
                sec, nanosec, self.arm.position.tolist() + list(self.orientation)))

    def _publish_diagnostics(self):
        """Publish the slave port's energies, drift, and the master-to-slave delay and loss."""
        port = self.port
        values = {'passivity': 'on' if port.enabled else 'off',
                  'slave energy in (J)': f'{port.energy_in:.4f}',
                  'slave energy out (J)': f'{port.energy_out:.4f}',
                  'slave energy dissipated (J)': f'{port.dissipated:.4f}',
                  'slave energy observed (J)': f'{port.observed:.4f}',
                  'drift (mm)': f'{1e3 * math.hypot(*port.drift):.3f}'}
        link = self.pose_link.summary()
        if link is not None:
            values.update({f'master to slave delay {label} (ms)': f'{1e3 * seconds:.3f}'
                           for label, seconds in zip(('median', 'p99', 'max'), link[:3])})
            values['master to slave loss (%)'] = f'{100.0 * link[3]:.1f}'
        array = DiagnosticArray(status=[DiagnosticStatus(
            name=f'{self.get_fully_qualified_name()}: simulated slave', level=DiagnosticStatus.OK,
            message=self.mode, values=[KeyValue(key=k, value=v) for k, v in values.items()])])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(array)


def main(args=None):
    """Run the slave until Ctrl-C or SIGTERM; exit 1 on a bad parameter."""
    return run_node(SlaveSimNode, 'kraft_master_slave_sim', __doc__.strip().splitlines()[0],
                    PARAMETERS, args)


if __name__ == '__main__':
    sys.exit(main())
