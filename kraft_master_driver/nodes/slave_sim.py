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

The arm, its servo and its environment are simulation/arms/point_mass.py (no ROS); this node
only moves messages.
"""
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from kraft_master_driver.core.teleoperation_settings import Settings
from kraft_master_driver.nodes import cdr
from kraft_master_driver.nodes.node_process import run_node
from kraft_master_driver.nodes.parameters import (
    declare_parameters, ParameterError, Spec)
from kraft_master_driver.nodes.ros_io import PacedThread, steady_timer, subscribe_raw, take_all
from kraft_master_driver.simulation.arms.point_mass import (
    ArmServo, checked_number, MAX_CATCH_UP, MODES, SlaveArm, SlaveLimits, SoftBox, Wall)
import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

TICK_QUEUE = 10  # messages a topic taken by the ticks holds between two ticks

POSE_STAMPED = cdr.StampedDoublesDecoder('PoseStamped', 7)
TWIST_STAMPED = cdr.StampedDoublesDecoder('TwistStamped', 6)
_DEFAULT_LIMITS = SlaveLimits()
_BRIDGE = Settings()

PARAMETERS = {
    'mode': Spec('pose', "'pose': follow servo_cp, a target pose; 'twist': servo_cv, a "
                 'velocity.', choices=MODES),
    'rate_hz': Spec(500.0, 'Simulation and publishing rate (Hz).'),
    'start_position': Spec([0.0, 0.0, 0.0], 'Where the tool starts, at rest (m, arm_frame); '
                           'on the wall if behind it.', length=3),
    'command_timeout': Spec(0.1, 'An older command makes the arm hold still (s).'),
    'max_velocity': Spec(_DEFAULT_LIMITS.max_velocity, 'Arm speed limit (m/s).'),
    'max_acceleration': Spec(_DEFAULT_LIMITS.max_acceleration, 'Arm servo acceleration '
                             'limit (m/s^2); times mass, the largest force it pushes with.'),
    'mass': Spec(_DEFAULT_LIMITS.mass, 'Moving mass of the arm (kg).'),
    'position_gain': Spec(_DEFAULT_LIMITS.position_gain, 'Position loop gain (1/s).'),
    'velocity_gain': Spec(_DEFAULT_LIMITS.velocity_gain, 'Velocity loop gain (1/s).'),
    'wall.point': Spec([0.0, 0.0, -0.04], 'A point of the wall plane (m), arm_frame.',
                       length=3),
    'wall.normal': Spec([0.0, 0.0, 1.0], 'Wall normal, pointing into free space.', length=3),
    'wall.stiffness': Spec(20000.0, 'Wall stiffness (N/m); 0 removes the wall.'),
    'wall.damping': Spec(100.0, 'Wall damping (N*s/m).'),
    'box.centre': Spec([0.0, 0.12, 0.0], 'Centre of the soft box (m), arm_frame.', length=3),
    'box.half_sizes': Spec([0.1, 0.06, 0.04], 'Half sizes of the soft box along x, y, z (m).',
                           length=3),
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
            rate_hz = checked_number('rate_hz', config['rate_hz'], positive=True)
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
        # The commands are taken raw by each tick (nodes/ros_io.py), all that came since the
        # last (the newest wins): the executor never wakes for them.
        msg_type, topic, on_message = (
            (PoseStamped, 'servo_cp', self._on_servo_cp) if self.servo.mode == 'pose'
            else (TwistStamped, 'servo_cv', self._on_servo_cv))
        self._command_sub = subscribe_raw(self, msg_type, topic, on_message, TICK_QUEUE)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', state_qos)
        steady_timer(self, 1.0, self._publish_diagnostics)
        self.last_tick = time.monotonic()
        # A thread of its own paces the ticks: with an executor's timer the process took about
        # twice the CPU (measured).
        self._ticks = PacedThread(self, 'slave_sim', 1.0 / rate_hz, self._tick)
        self._ticks.start()
        self.get_logger().info(
            f'simulated arm in {self.servo.mode} mode at {rate_hz:g} Hz, tool at '
            f'({", ".join(f"{v:.4f}" for v in arm.position)}) m in {self.arm_frame}; wall '
            f'{"on" if arm.wall else "off"}, soft box {"on" if arm.box else "off"}')

    def _take_all(self, subscription):
        """Hand each command that came (CDR bytes, oldest first) on; refuse bad ones."""
        for data in take_all(subscription):
            try:
                subscription.callback(data)
            except ValueError as error:
                self.refused += 1
                self.servo.refuse()
                self.get_logger().error(f'{subscription.topic_name} refused, holding: {error}',
                                        throttle_duration_sec=1.0)

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

    def destroy_node(self):
        """Stop the ticks, then the node."""
        self._ticks.stop()
        super().destroy_node()

    def _tick(self, _missed):
        """Take the commands, advance the arm by the time elapsed, publish its state."""
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
