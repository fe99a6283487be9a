# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_arm_sim: a Franka Panda simulated in MuJoCo, speaking an arm's CRTK topics.

It takes `servo_cp` (PoseStamped: the tool's target) or `servo_cv` (TwistStamped: a velocity
that moves the target) in `arm_frame`, and publishes `measured_cp` (the tool's pose in
`arm_frame`), `measured_js` (JointState) and `measured_cf` (the wrist F/T sensor's reading in
`ft_frame`: the wrench the tool applies to the sensor), as the arm side of kraft_master_teleop
expects them. The physics steps 1 ms at a time, paced to the wall clock, and its real-time
factor is in the diagnostics. A command command_timeout old or older, or none, holds the arm
still. The arm, its controller and its table are simulation.arms.panda.PandaArm (no ROS);
this node only moves messages. For fault rehearsals, ft_fault (settable at run time) makes the
wrist sensor drop out, read NaN, stick, spike or change its frame.
"""
import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TwistStamped, Vector3Stamped, WrenchStamped
from kraft_master_driver.nodes import cdr
from kraft_master_driver.nodes.node_process import run_node
from kraft_master_driver.nodes.parameters import (
    declare_parameters, ParameterError, run_time_changes, Spec)
from kraft_master_driver.nodes.ros_io import (
    GIL_SWITCH_INTERVAL_S, PacedThread, steady_timer, subscribe_raw, take_all)
from kraft_master_driver.simulation.arms.panda import (
    ArmModelMissing, Gains, JOINT_NAMES, PandaArm, SensorModel, Table)
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

MAX_CATCH_UP_STEPS = 20  # steps run at once after a late wake-up; time beyond is dropped
TICK_QUEUE = 10
# The wrist sensor's faults that ft_fault switches on, for fault rehearsals.
FT_FAULTS = ('none', 'dropout', 'nan', 'stuck', 'spike', 'frame')
SPIKE_N = 1e4  # N added along the sensor's z by a 'spike': ten times the bridge's input limit

POSE_STAMPED = cdr.StampedDoublesDecoder('PoseStamped', 7)
TWIST_STAMPED = cdr.StampedDoublesDecoder('TwistStamped', 6)

_GAINS, _TABLE, _SENSOR = Gains(), Table(), SensorModel()

PARAMETERS = {
    'publish_rate_hz': Spec(500.0, 'Rate of measured_cp, measured_cf, measured_js and '
                            'table_force (Hz); the physics always steps at 1 kHz.', low=1.0,
                            high=1000.0),
    'arm_frame': Spec('base_link', 'frame_id of servo_cp, servo_cv, measured_cp and '
                      "table_force: the arm's base frame."),
    'ft_frame': Spec('ft_sensor', 'frame_id of measured_cf: the F/T sensor at the flange, '
                     'turned as the tool frame.'),
    'command_timeout': Spec(0.1, 'A servo_cp or servo_cv this old holds the arm where it is '
                            '(s).', low=0.001, high=10.0),
    'translational_stiffness': Spec(_GAINS.translational_stiffness, 'Cartesian stiffness '
                                    '(N/m).', low=1.0, high=5000.0),
    'rotational_stiffness': Spec(_GAINS.rotational_stiffness, 'Rotational stiffness '
                                 '(N*m/rad).', low=0.1, high=300.0),
    'damping_ratio': Spec(_GAINS.damping_ratio, 'Damping: 2 * ratio * sqrt(stiffness) (1).',
                          low=0.0, high=10.0),
    'nullspace_stiffness': Spec(_GAINS.nullspace_stiffness, 'Pull toward the ready posture in '
                                "the task's nullspace (N*m/rad).", low=0.0, high=100.0),
    'joint_damping': Spec(_GAINS.joint_damping, 'Viscous friction of each joint '
                          '(N*m*s/rad).', low=0.0, high=100.0),
    'max_position_error': Spec(_GAINS.max_position_error, 'A farther target pulls as if this '
                               'far (m).', low=0.001, high=1.0),
    'max_rotation_error': Spec(_GAINS.max_rotation_error, 'A target turned farther pulls as if '
                               'turned this far (rad).', low=0.001, high=math.pi),
    'table.centre': Spec(list(_TABLE.centre), "x, y of the table top's middle (m, arm base "
                         'frame).', length=2),
    'table.half_sizes': Spec(list(_TABLE.half_sizes), 'Half the table top along x and y (m).',
                             length=2),
    'table.height': Spec(_TABLE.height, 'Height of the table top (m, arm base frame).'),
    'table.stiffness': Spec(_TABLE.stiffness, 'Stiffness of the spring under the table top (N/m).',
                            low=10.0, high=1e6),
    'table.damping': Spec(_TABLE.damping, 'Damping of the spring under the table top (N*s/m).',
                          low=0.0, high=1e4),
    'table.friction': Spec(_TABLE.friction, 'Friction coefficient of the table and the '
                           'fingertips (1).', low=0.0, high=2.0),
    'force_bias': Spec(list(_SENSOR.force_bias), 'Constant bias added to the F/T force (N).',
                       length=3),
    'torque_bias': Spec(list(_SENSOR.torque_bias), 'Constant bias added to the F/T moment '
                        '(N*m).', length=3),
    'force_noise': Spec(_SENSOR.force_noise, 'Standard deviation of white noise on each force '
                        'axis (N).', low=0.0, high=100.0),
    'torque_noise': Spec(_SENSOR.torque_noise, 'Standard deviation of white noise on each '
                         'moment axis (N*m).', low=0.0, high=10.0),
    'ft_fault': Spec('none', "A fault of the F/T sensor, for rehearsals: 'dropout' publishes "
                     "no measured_cf, 'nan' NaN in every axis, 'stuck' the reading of the "
                     "moment it was set, 'spike' 10 kN more along z, 'frame' the frame_id "
                     "ft_frame + '_moved'; 'none' the true reading.", read_only=False,
                     choices=FT_FAULTS),
}


def _make_arm(config):
    """Return the PandaArm the parameters describe; ParameterError naming a bad one."""
    try:
        table = Table(*(config[f'table.{name}'] for name in Table._fields))
        gains = Gains(*(config[name] for name in Gains._fields))
        sensor = SensorModel(*(config[name] for name in SensorModel._fields))
        return PandaArm(table.checked(), gains, sensor, config['command_timeout'])
    except ValueError as error:
        raise ParameterError(f'parameter {error}') from None
    except ArmModelMissing as error:
        raise ParameterError(f'cannot build the arm: {error}') from None


class ArmSimNode(Node):
    """Steps a PandaArm at 1 kHz in a thread of its own and moves its messages."""

    def __init__(self, params_files=(), **kwargs):
        """Declare and check the parameters, build the arm, start the physics thread."""
        super().__init__('kraft_master_arm_sim', **kwargs)
        config = declare_parameters(self, PARAMETERS, params_files)
        self.arm = _make_arm(config)
        self.arm_frame = config['arm_frame']
        self.publish_period = 1.0 / config['publish_rate_hz']
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pose_pub = self.create_publisher(PoseStamped, 'measured_cp', reliable)
        self.wrench_pub = self.create_publisher(WrenchStamped, 'measured_cf', reliable)
        self.joints_pub = self.create_publisher(JointState, 'measured_js', reliable)
        self.table_pub = self.create_publisher(Vector3Stamped, 'table_force', reliable)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', reliable)
        self._pose_cdr = cdr.StampedDoublesEncoder(self.arm_frame, 7)
        self._wrench_cdr = cdr.StampedDoublesEncoder(config['ft_frame'], 6)
        self._moved_wrench_cdr = cdr.StampedDoublesEncoder(config['ft_frame'] + '_moved', 6)
        self.ft_fault = config['ft_fault']
        self._stuck_reading = None
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._joints_cdr = cdr.JointStateEncoder('', JOINT_NAMES, (7, 7, 7))
        self._table_cdr = cdr.StampedDoublesEncoder(self.arm_frame, 3)
        # Taken raw by the physics thread (nodes/ros_io.py), all that came at each step.
        self._pose_sub = subscribe_raw(self, PoseStamped, 'servo_cp', self._on_servo_cp,
                                       TICK_QUEUE)
        self._twist_sub = subscribe_raw(self, TwistStamped, 'servo_cv', self._on_servo_cv,
                                        TICK_QUEUE)
        self._refusals = 0
        self._last_refusal = ''
        self._window = (time.monotonic(), self.arm.time)  # wall and simulated time
        self.real_time_factor = None
        self._steps = 0
        self._step_seconds = 0.0  # CPU seconds spent stepping, this window
        self._dropped = 0.0  # s of simulated time skipped after stalls, in all
        self._next_publish = 0.0  # simulated time of the next measured_* messages
        self._snapshot = (self.arm.tool_position(), self.arm.table_contact_force(), True)
        steady_timer(self, 1.0, self._publish_diagnostics)
        sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
        self._physics = PacedThread(self, 'arm_sim', self.arm.model.opt.timestep, self._step)
        self._physics.start()
        mass, com = self.arm.tool_mass_properties()
        position = self.arm.tool_position()
        self.get_logger().info(
            'Panda at ' + ', '.join(f'{v:.3f}' for v in position) + ' m, table top at '
            f'{config["table.height"]:g} m; tool {mass:.4f} kg, centre of mass '
            + ', '.join(f'{v:.4f}' for v in com) + f' m in {config["ft_frame"]} (the bridge\'s '
            'tool_mass and tool_com)')

    def _take_all(self, subscription):
        """Hand each message that came, oldest first, to the subscription's callback."""
        for data in take_all(subscription):
            self._refused(subscription.callback(data))

    def _refused(self, refusal):
        if refusal is not None:
            self._refusals += 1
            self._last_refusal = refusal
            self.get_logger().error(refusal, throttle_duration_sec=1.0)

    def _decoded(self, decoder, topic, data):
        """Return the values of a command in arm_frame, or the one line refusing it."""
        try:
            _, _, frame_id, values = decoder.decode(data)
        except ValueError as error:
            return None, f'{topic} refused: {error}'
        if frame_id != self.arm_frame:
            return None, (f'{topic} refused: frame_id {frame_id!r}, expected '
                          f'{self.arm_frame!r}')
        return values, None

    def _on_servo_cp(self, data):
        values, refusal = self._decoded(POSE_STAMPED, 'servo_cp', data)
        if refusal is None:
            refusal = self.arm.command_pose(values[:3], values[3:], time.monotonic())
        return refusal

    def _on_servo_cv(self, data):
        values, refusal = self._decoded(TWIST_STAMPED, 'servo_cv', data)
        if refusal is None:
            refusal = self.arm.command_twist(values[:3], values[3:], time.monotonic())
        return refusal

    def _on_set_parameters(self, parameters):
        """Take a run-time ft_fault; every other parameter is fixed at start-up."""
        try:
            changes = run_time_changes(PARAMETERS, parameters)
        except ParameterError as error:
            return SetParametersResult(successful=False, reason=str(error))
        if 'ft_fault' in changes:
            self._stuck_reading = None
            self.ft_fault = changes['ft_fault']
            self.get_logger().warning(f'F/T sensor fault: {self.ft_fault}')
        return SetParametersResult(successful=True)

    def _sensor_message(self, sec, nanosec):
        """Return measured_cf as CDR bytes, with the ft_fault switched on; None: no message."""
        fault, reading = self.ft_fault, self.arm.wrench()
        if fault == 'dropout':
            return None
        if fault == 'nan':
            reading[:] = math.nan
        elif fault == 'stuck':
            if self._stuck_reading is None:
                self._stuck_reading = reading
            reading = self._stuck_reading
        elif fault == 'spike':
            reading[2] += SPIKE_N
        encoder = self._moved_wrench_cdr if fault == 'frame' else self._wrench_cdr
        return encoder.encode(sec, nanosec, reading.tolist())

    # -- the physics thread ------------------------------------------------------------

    def _step(self, missed):
        """
        Step the physics for the period due and the `missed` ones, at most MAX_CATCH_UP_STEPS.

        Run by the physics thread (ros_io.PacedThread) on the wall clock's 1 ms grid until
        destroy_node() or the context's end.
        """
        dt = self.arm.model.opt.timestep
        due = 1 + missed
        if due > MAX_CATCH_UP_STEPS:  # a stall: drop the time beyond, do not replay it
            self._dropped += (due - MAX_CATCH_UP_STEPS) * dt
            due = MAX_CATCH_UP_STEPS
        self._take_all(self._pose_sub)
        self._take_all(self._twist_sub)
        began = time.thread_time()
        for _ in range(due):
            self.arm.step(time.monotonic())
        self._step_seconds += time.thread_time() - began
        self._steps += due
        if self.arm.time >= self._next_publish:
            self._next_publish = self.arm.time + self.publish_period - dt / 2.0
            self._publish_measured()

    def destroy_node(self):
        """Stop the physics thread, then the node."""
        self._physics.stop()
        super().destroy_node()

    def _publish_measured(self):
        arm = self.arm
        sec, nanosec = divmod(self.get_clock().now().nanoseconds, 1_000_000_000)
        position = arm.tool_position()
        table_force = arm.table_contact_force()
        # For the diagnostics, which run in the executor's thread.
        self._snapshot = (position, table_force, arm.holding)
        self.pose_pub.publish(self._pose_cdr.encode(
            sec, nanosec, [*position.tolist(), *arm.tool_quaternion()]))
        sensor = self._sensor_message(sec, nanosec)
        if sensor is not None:
            self.wrench_pub.publish(sensor)
        self.joints_pub.publish(self._joints_cdr.encode(
            sec, nanosec, arm.joint_positions().tolist(), arm.joint_velocities().tolist(),
            arm.torque.tolist()))
        self.table_pub.publish(self._table_cdr.encode(sec, nanosec, table_force.tolist()))

    def _publish_diagnostics(self):
        """Publish the real-time factor, the cost of a step and the arm's state, at 1 Hz."""
        now, arm = time.monotonic(), self.arm
        wall, simulated = now - self._window[0], arm.time - self._window[1]
        self._window = (now, arm.time)
        self.real_time_factor = simulated / wall if wall > 0.0 else None
        step_us = 1e6 * self._step_seconds / self._steps if self._steps else float('nan')
        self._steps, self._step_seconds = 0, 0.0
        position, contact, holding = self._snapshot
        values = {
            'real-time factor': f'{self.real_time_factor:.3f}',
            'step CPU (us)': f'{step_us:.1f}',
            'dropped after stalls (s)': f'{self._dropped:.3f}',
            'command': 'holding' if holding else 'following',
            'tool position (m)': ', '.join(f'{v:.4f}' for v in position),
            'table contact force (N)': ', '.join(f'{v:.2f}' for v in contact),
            'refused commands': str(self._refusals),
            'last refusal': self._last_refusal,
        }
        level = DiagnosticStatus.OK if self.real_time_factor >= 0.95 else DiagnosticStatus.WARN
        message = ('real time' if level == DiagnosticStatus.OK
                   else f'slower than real time: {self.real_time_factor:.2f}')
        array = DiagnosticArray(status=[DiagnosticStatus(
            name=f'{self.get_fully_qualified_name()}: simulated arm', level=level,
            message=message, values=[KeyValue(key=k, value=v) for k, v in values.items()])])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(array)


def main(args=None):
    """Run the simulated arm until Ctrl-C or SIGTERM; exit 1 on a bad parameter."""
    return run_node(ArmSimNode, 'kraft_master_arm_sim', __doc__.strip().splitlines()[0],
                    PARAMETERS, args)


if __name__ == '__main__':
    sys.exit(main())
