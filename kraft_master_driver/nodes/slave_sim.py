# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_slave_sim: a simulated arm that speaks the arm-side topics of the bridge.

The arm is a point mass (its tool point) servoed toward a target with velocity and
acceleration limits, in an environment with a stiff virtual wall and a soft box. As a real
arm's ROS stack would, it takes `servo_cp` (pose mode: the target pose) or `servo_cv` (twist
mode: the tool's velocity), both in `arm_frame`, and publishes `measured_cp` (the tool pose in
`arm_frame`) and `measured_cf` (the wrench the tool applies to its wrist sensor, frame
`ft_frame`: the environment's contact force turned into the tool's frame). It does not move
before its first command, and holds still once the newest command is older than
`command_timeout`. kraft_master_teleop maps the master to it and reflects its contacts.

SlaveArm, Wall, SoftBox and ArmServo are plain Python (no ROS) and unit-tested; the node below
them only moves messages.
"""
import math
import sys
import threading
import time
from typing import NamedTuple

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from kraft_master_driver.core.teleoperation import quaternion_to_rotation, Settings
from kraft_master_driver.link import cdr
from kraft_master_driver.nodes.lifecycle import run_node
from kraft_master_driver.nodes.parameters import (
    declare_parameters, ParameterError, Spec)
from kraft_master_driver.nodes.ros_helpers import steady_timer, TakenByLoopThread
import numpy as np
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

MODES = ('pose', 'twist')
MAX_STEP = 0.002  # s, longest integration step
MAX_CATCH_UP = 0.1  # s of simulated time per advance(); a longer stall is skipped, not replayed
TICK_QUEUE = 10  # messages a topic taken by the ticks holds between two ticks
QUATERNION_TOLERANCE = 0.01  # |q| of a servo_cp may differ from 1 by this much


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


class ArmServo:
    """
    What the arm does with its commands: follow the newest while fresh, else hold still.

    Pose mode servoes the arm toward the commanded position and takes the commanded
    orientation; twist mode moves it at the commanded velocity and turns the orientation at
    the commanded angular velocity. Until the first command the arm holds where it started;
    once the newest command is older than `timeout` s it holds where it was then. Times are
    monotonic seconds given by the caller.
    """

    def __init__(self, arm, mode, timeout):
        """Servo `arm` (a SlaveArm already reset) in `mode` ('pose' or 'twist')."""
        if mode not in MODES:
            raise ValueError(f'mode must be one of {", ".join(MODES)}, got {mode!r}')
        self.arm = arm
        self.mode = mode
        self.timeout = _number('command_timeout', timeout, positive=True)
        self.orientation = (0.0, 0.0, 0.0, 1.0)
        self.hold = arm.position.copy()
        self.command = None  # (position or (linear, angular), receipt time) of the newest

    def pose_command(self, position, quaternion, now):
        """Take a target pose (m; unit quaternion x, y, z, w); raise ValueError if bad."""
        position = _vector('servo_cp position', position)
        quaternion = np.array(quaternion, dtype=float)
        norm = float(np.linalg.norm(quaternion))
        if not np.all(np.isfinite(quaternion)) or abs(norm - 1.0) > QUATERNION_TOLERANCE:
            raise ValueError(f'servo_cp orientation is not a unit quaternion: '
                             f'{quaternion.tolist()}')
        self.command = (position, now)
        self.orientation = tuple((quaternion / norm).tolist())

    def twist_command(self, linear, angular, now):
        """Take a velocity (m/s) and angular velocity (rad/s); raise ValueError if bad."""
        self.command = ((_vector('servo_cv linear', linear),
                         _vector('servo_cv angular', angular)), now)

    def refuse(self):
        """Drop the command after a refused one: the arm holds where it is."""
        self.command = None

    def fresh(self, now):
        """Return whether the newest command is younger than the timeout."""
        return self.command is not None and now - self.command[1] <= self.timeout

    def advance(self, elapsed, now):
        """Run the arm `elapsed` s toward the command it has at `now`; return the contact force."""
        if self.fresh(now):
            self.hold = None
            if self.mode == 'pose':
                return self.arm.advance(elapsed, target=self.command[0])
            linear, angular = self.command[0]
            self.orientation = integrate_quaternion(self.orientation, angular, elapsed)
            return self.arm.advance(elapsed, velocity=linear)
        if self.hold is None:
            self.hold = self.arm.position.copy()
        return self.arm.advance(elapsed, target=self.hold)

    def sensor_wrench(self, contact_force):
        """Return the wrench (6) the tool applies to its wrist sensor, in the tool's frame."""
        rotation = quaternion_to_rotation(self.orientation)
        return np.concatenate([rotation.T @ np.asarray(contact_force, dtype=float),
                               np.zeros(3)])


# -- the node ---------------------------------------------------------------------------

POSE_STAMPED = cdr.StampedDoublesDecoder('PoseStamped', 7)
TWIST_STAMPED = cdr.StampedDoublesDecoder('TwistStamped', 6)
_DEFAULT_LIMITS = SlaveLimits()
_BRIDGE = Settings()

PARAMETERS = {
    'mode': Spec('pose', "'pose': follow servo_cp, a target pose; 'twist': servo_cv, a "
                 'velocity.', choices=MODES),
    'rate_hz': Spec(500.0, 'Simulation and publishing rate (Hz).'),
    'start_position': Spec([0.0, 0.0, 0.0], 'Where the tool starts, at rest (m, arm_frame); '
                           'on the wall if behind it.'),
    'command_timeout': Spec(0.1, 'An older command makes the arm hold still (s).'),
    'max_velocity': Spec(_DEFAULT_LIMITS.max_velocity, 'Arm speed limit (m/s).'),
    'max_acceleration': Spec(_DEFAULT_LIMITS.max_acceleration, 'Arm servo acceleration '
                             'limit (m/s^2); times mass, the largest force it pushes with.'),
    'mass': Spec(_DEFAULT_LIMITS.mass, 'Moving mass of the arm (kg).'),
    'position_gain': Spec(_DEFAULT_LIMITS.position_gain, 'Position loop gain (1/s).'),
    'velocity_gain': Spec(_DEFAULT_LIMITS.velocity_gain, 'Velocity loop gain (1/s).'),
    'wall.point': Spec([0.0, 0.0, -0.04], 'A point of the wall plane (m), arm_frame.'),
    'wall.normal': Spec([0.0, 0.0, 1.0], 'Wall normal, pointing into free space.'),
    'wall.stiffness': Spec(20000.0, 'Wall stiffness (N/m); 0 removes the wall.'),
    'wall.damping': Spec(100.0, 'Wall damping (N*s/m).'),
    'box.centre': Spec([0.0, 0.12, 0.0], 'Centre of the soft box (m), arm_frame.'),
    'box.half_sizes': Spec([0.1, 0.06, 0.04], 'Half sizes of the soft box along x, y, z (m).'),
    'box.stiffness': Spec(200.0, 'Soft box stiffness (N/m); 0 removes the box.'),
    'box.damping': Spec(20.0, 'Soft box damping (N*s/m).'),
    'arm_frame': Spec(_BRIDGE.arm_frame, 'frame_id of servo_cp, servo_cv and measured_cp: the '
                      "arm's base frame (the bridge's arm_frame)."),
    'ft_frame': Spec(_BRIDGE.ft_frame, "frame_id of measured_cf: the wrist sensor's frame, "
                     "the tool's (the bridge's ft_frame)."),
}


class SlaveSimNode(Node):
    """Runs a SlaveArm after servo_cp or servo_cv; publishes measured_cp and measured_cf."""

    def __init__(self, params_files=(), **kwargs):
        """Declare and check the parameters, then start the fixed-rate simulation thread."""
        super().__init__('kraft_master_slave_sim', **kwargs)
        config = declare_parameters(self, PARAMETERS, params_files)
        try:
            rate_hz = _number('rate_hz', config['rate_hz'], positive=True)
            wall = Wall(config['wall.point'], config['wall.normal'], config['wall.stiffness'],
                        config['wall.damping'])
            box = SoftBox(config['box.centre'], config['box.half_sizes'],
                          config['box.stiffness'], config['box.damping'])
            arm = SlaveArm(SlaveLimits(*(config[name] for name in SlaveLimits._fields)),
                           wall if wall.stiffness > 0.0 else None,
                           box if box.stiffness > 0.0 else None)
            arm.reset(config['start_position'])
            self.servo = ArmServo(arm, config['mode'], config['command_timeout'])
        except ValueError as error:
            raise ParameterError(f'parameter {error}') from None
        self.arm_frame = config['arm_frame']
        self.ft_frame = config['ft_frame']
        self.refused = 0  # commands refused: wrong frame or bad values

        state_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pose_pub = self.create_publisher(PoseStamped, 'measured_cp', state_qos)
        self.wrench_pub = self.create_publisher(WrenchStamped, 'measured_cf', state_qos)
        self._pose_cdr = cdr.StampedDoublesEncoder(self.arm_frame, 7)
        self._wrench_cdr = cdr.StampedDoublesEncoder(self.ft_frame, 6)
        # The commands are taken raw by each tick, all that came since the last (the newest
        # wins): the executor never wakes for them.
        msg_type, topic, on_message = (
            (PoseStamped, 'servo_cp', self._on_servo_cp) if self.servo.mode == 'pose'
            else (TwistStamped, 'servo_cv', self._on_servo_cv))
        self._command_sub = self.create_subscription(
            msg_type, topic, on_message,
            QoSProfile(depth=TICK_QUEUE, reliability=ReliabilityPolicy.BEST_EFFORT), raw=True,
            callback_group=TakenByLoopThread(),
            event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', state_qos)
        steady_timer(self, 1.0, self._publish_diagnostics)
        self.last_tick = time.monotonic()
        # A thread of its own paces the ticks: with an executor's timer the process took about
        # twice the CPU (measured).
        self._period = 1.0 / rate_hz
        self._running = True
        self._thread = threading.Thread(target=self._run, name='slave_sim')
        self._thread.start()
        self.get_logger().info(
            f'simulated arm in {self.servo.mode} mode at {rate_hz:g} Hz, tool at '
            f'({", ".join(f"{v:.4f}" for v in arm.position)}) m in {self.arm_frame}; wall '
            f'{"on" if arm.wall else "off"}, soft box {"on" if arm.box else "off"}')

    def _take_all(self, subscription):
        """Hand each command that came (CDR bytes, oldest first) on; refuse bad ones."""
        with subscription.handle:
            while (taken := subscription.handle.take_message(
                    subscription.msg_type, True)) is not None:
                try:
                    subscription.callback(taken[0])
                except ValueError as error:
                    self.refused += 1
                    self.servo.refuse()
                    self.get_logger().error(f'{subscription.topic_name} refused, holding: '
                                            f'{error}', throttle_duration_sec=1.0)

    def _checked_frame(self, frame_id):
        if frame_id != self.arm_frame:
            raise ValueError(f'frame_id {frame_id!r} is not arm_frame {self.arm_frame!r}')

    def _on_servo_cp(self, data):
        _, _, frame_id, values = POSE_STAMPED.decode(data)
        self._checked_frame(frame_id)
        self.servo.pose_command(values[:3], values[3:], time.monotonic())

    def _on_servo_cv(self, data):
        _, _, frame_id, values = TWIST_STAMPED.decode(data)
        self._checked_frame(frame_id)
        self.servo.twist_command(values[:3], values[3:], time.monotonic())

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
        now = time.monotonic()
        elapsed, self.last_tick = min(now - self.last_tick, MAX_CATCH_UP), now
        force = self.servo.advance(elapsed, now)
        sec, nanosec = divmod(self.get_clock().now().nanoseconds, 1_000_000_000)
        self.pose_pub.publish(self._pose_cdr.encode(
            sec, nanosec, self.servo.arm.position.tolist() + list(self.servo.orientation)))
        self.wrench_pub.publish(self._wrench_cdr.encode(
            sec, nanosec, self.servo.sensor_wrench(force).tolist()))

    def _publish_diagnostics(self):
        """Publish whether the arm follows or holds, its contact force and refused commands."""
        servo = self.servo
        values = {'command': 'following' if servo.fresh(time.monotonic()) else 'holding',
                  'contact force (N)': f'{float(np.linalg.norm(servo.arm.contact_force())):.3f}',
                  'refused commands': str(self.refused)}
        array = DiagnosticArray(status=[DiagnosticStatus(
            name=f'{self.get_fully_qualified_name()}: simulated arm', level=DiagnosticStatus.OK,
            message=servo.mode, values=[KeyValue(key=k, value=v) for k, v in values.items()])])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(array)


def main(args=None):
    """Run the arm until Ctrl-C or SIGTERM; exit 1 on a bad parameter."""
    return run_node(SlaveSimNode, 'kraft_master_slave_sim', __doc__.strip().splitlines()[0],
                    PARAMETERS, args)


if __name__ == '__main__':
    sys.exit(main())
