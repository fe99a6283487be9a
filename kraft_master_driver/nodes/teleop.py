# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_teleop: the bridge between the Kraft Master's driver and a real arm.

Master side, the driver's names: it takes `pose` and `master_energy`, publishes `wrench`,
`slave_energy` and `contact_model` (the contact it estimates, for the driver to render). Arm
side, CRTK names to remap: it publishes `servo_cp` (pose mode) or `servo_cv` (twist mode) and
takes `measured_cp` and `measured_cf`. `clutch` (or a `joy`
button) holds the arm and frees the master; the services `enable` and `tare` start it and zero
the F/T bias. The logic is core.teleoperation.Teleoperation: each input and each tick goes in
as one call and comes back as what to send; this node decodes, calls and publishes.

The four streaming inputs (pose, master_energy, measured_cp, measured_cf) are taken raw by a
thread of their own that waits on them alone and handles each message as it comes
(nodes/ros_io.py), and servo_cp, servo_cv and wrench go out as CDR bytes (nodes/cdr.py):
through rclpy's typed messages and executor the bridge kept up with about one pose in 15 at
1 kHz (benchmarks/bridge.py). The executor serves the rest: clutch, joy, services, timers,
and the parameter service: a run-time set is checked as at start-up and handed to the bridge
under the lock its inputs take (Teleoperation.configure: one new Settings, all at once).
"""
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TwistStamped, Vector3Stamped, WrenchStamped
from kraft_master_driver.core import realtime
from kraft_master_driver.core.contact_model import MODEL_FIELDS
from kraft_master_driver.core.link_quality import LinkMonitor
from kraft_master_driver.core.teleoperation import NoBaseRotation, OperatingState, Teleoperation
from kraft_master_driver.core.teleoperation_settings import Settings
from kraft_master_driver.nodes import cdr
from kraft_master_driver.nodes.driver_diagnostics import ERROR, OK
from kraft_master_driver.nodes.node_process import run_node
from kraft_master_driver.nodes.parameters import (
    declare_parameters, ParameterError, run_time_changes)
from kraft_master_driver.nodes.ros_io import (
    GIL_SWITCH_INTERVAL_S, InputWaitSet, run_paced, steady_timer, subscribe_raw,
    take_oldest_received)
from kraft_master_driver.nodes.teleop_diagnostics import bridge_diagnostics
from kraft_master_driver.nodes.teleop_parameters import PARAMETERS
from rcl_interfaces.msg import SetParametersResult
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.time import Time
from sensor_msgs.msg import JointState, Joy
from std_msgs.msg import Bool, String
from std_srvs.srv import SetBool, Trigger

POSE_STAMPED = cdr.StampedDoublesDecoder('PoseStamped', 7)
VECTOR3_STAMPED = cdr.StampedDoublesDecoder('Vector3Stamped', 3)
DIAGNOSTIC_LEVELS = {OK: DiagnosticStatus.OK, ERROR: DiagnosticStatus.ERROR}


def with_values(settings, values):
    """Return `settings` with the parameter values among `values` that are Settings' fields."""
    return settings._replace(**{
        name: tuple(value) if isinstance(value, list) else value
        for name, value in values.items() if name in Settings._fields})


class TeleopNode(Node):
    """Moves messages between the master, the arm and a Teleoperation."""

    def __init__(self, params_files=(), **kwargs):
        """Declare and check the parameters, then wire the topics and services."""
        super().__init__('kraft_master_teleop', **kwargs)
        config = declare_parameters(self, PARAMETERS, params_files)
        try:
            self.bridge = Teleoperation(with_values(Settings(), config))
        except ValueError as error:
            raise ParameterError(f'parameter {error}') from None
        self.mode = config['mode']
        self.clutch_button = config['clutch_button']
        self.enable_at_start = config['enable_at_start']
        self.pose_link = LinkMonitor()  # the master's pose: delay and loss on the way here
        self._base_rotation_from_tf = (self._tf_lookup() if config['base_rotation_from_tf']
                                       else None)
        self._clutch_inputs = {'clutch': False, 'joy': False}
        self._input_priority = config['input_priority']
        self._executor_thread = threading.get_native_id()  # the thread that will spin the node
        self.scheduling = realtime.Scheduling()
        # The bridge and the publishers are used by the input thread and the executor alike.
        self._lock = threading.Lock()
        settings = self.bridge.settings
        self._servo_cdr = cdr.StampedDoublesEncoder(settings.arm_frame,
                                                    7 if self.mode == 'pose' else 6)
        self._wrench_cdr = cdr.StampedDoublesEncoder(settings.master_frame, 6)
        self._energy_cdr = cdr.StampedDoublesEncoder(settings.master_frame, 3)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        # No QoS event handlers: each is work for every wake-up of the executor (with them,
        # its wait-set bookkeeping alone took about 0.3 of a core here).
        quiet = {'event_callbacks': PublisherEventCallbacks(use_default_callbacks=False)}
        self.servo_pub = (self.create_publisher(PoseStamped, 'servo_cp', reliable, **quiet)
                          if self.mode == 'pose'
                          else self.create_publisher(TwistStamped, 'servo_cv', reliable, **quiet))
        self.wrench_pub = self.create_publisher(WrenchStamped, 'wrench', reliable, **quiet)
        self.energy_pub = self.create_publisher(Vector3Stamped, 'slave_energy', reliable, **quiet)
        self.model_pub = self.create_publisher(JointState, 'contact_model', reliable, **quiet)
        self.state_pub = self.create_publisher(String, 'operating_state', QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL), **quiet)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', reliable, **quiet)
        quiet_input = SubscriptionEventCallbacks(use_default_callbacks=False)
        self._inputs = tuple(
            subscribe_raw(self, msg_type, topic, handler, 10)
            for msg_type, topic, handler in (
                (PoseStamped, 'pose', self._on_pose),
                (Vector3Stamped, 'master_energy', self._on_master_energy),
                (PoseStamped, 'measured_cp', self._on_measured_cp),
                (WrenchStamped, 'measured_cf', self._on_measured_cf)))
        self.create_subscription(Bool, 'clutch', self._on_clutch, reliable,
                                 event_callbacks=quiet_input)
        if self.clutch_button >= 0:
            self.create_subscription(Joy, 'joy', self._on_joy, reliable,
                                     event_callbacks=quiet_input)
        self.create_service(SetBool, 'enable', self._on_enable)
        self.create_service(Trigger, 'tare', self._on_tare)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._tick_period = 1.0 / config['rate_hz']
        steady_timer(self, 1.0, self._publish_diagnostics)
        self._send(self.bridge.first_outputs())
        # The banner first: the input thread may enable the bridge at once (enable_at_start).
        self.get_logger().info(
            f'bridge in {self.mode} mode, scale {config["scale"]:g}, orientation '
            f'{config["orientation"]}; DISABLED until the enable service is called'
            + (' (enabled at start once it can be)' if self.enable_at_start else ''))
        self._running = True
        self._input_thread = threading.Thread(target=self._take_inputs, name='teleop_inputs')
        self._input_thread.start()

    def _tf_lookup(self):
        """
        Return a lookup of base_rotation in TF, from a Buffer this node's listener fills.

        The lookup returns the rotation of master_frame in arm_frame (x, y, z, w), or raises
        NoBaseRotation saying why there is none.
        """
        try:
            import tf2_ros
        except ImportError:
            raise ParameterError('base_rotation_from_tf needs tf2_ros, which is not installed '
                                 '(it is not on PyPI): install ROS 2 tf2_ros or give '
                                 'base_rotation') from None
        buffer = tf2_ros.Buffer()
        self._tf_listener = tf2_ros.TransformListener(buffer, self)
        settings = self.bridge.settings

        def look_up():
            try:
                rotation = buffer.lookup_transform(
                    settings.arm_frame, settings.master_frame, Time()).transform.rotation
            except tf2_ros.TransformException as error:
                raise NoBaseRotation(f'no TF from {settings.master_frame} to '
                                     f'{settings.arm_frame} ({error})') from None
            return rotation.x, rotation.y, rotation.z, rotation.w
        return look_up

    def destroy_node(self):
        """Stop the input thread, then the node."""
        self._running = False
        self._input_thread.join()
        super().destroy_node()

    # -- inputs ----------------------------------------------------------------------

    def _take_inputs(self):
        """
        Wait on the streaming inputs alone; handle each message as it comes, until stopped.

        The ticks (_tick, at rate_hz on the steady clock) run here too, between messages
        (ros_io.run_paced): as an executor timer each woke the executor, whose wait-set
        bookkeeping took about 2 ms of a loaded machine's CPU per wake-up (benchmarks/bridge.py
        --profile).
        """
        if self._input_priority:
            self.scheduling = realtime.make_real_time(
                self._input_priority, self._executor_thread, self.get_logger().warning,
                'input_priority', 'the input thread')
        run_paced(self._tick_period, lambda _missed: self._tick(),
                  lambda: self._running and self.context.ok(),
                  InputWaitSet(self.context, self._inputs), self._take_one_each)

    def _take_one_each(self):
        """
        Hand the oldest message of each input (CDR bytes) to its handler; return whether any.

        One of each in turn: were one input drained first, a pose stream the bridge cannot
        keep up with would leave measured_cp untaken until it went stale (a FAULT, seen under
        load).
        """
        taken_any = False
        for subscription in self._inputs:
            taken = take_oldest_received(subscription)
            if taken is None:
                continue
            taken_any = True
            with self._lock:
                try:
                    # When DDS received it (system clock, ns), not when this thread took it.
                    subscription.callback(*taken)
                except ValueError as error:
                    self.get_logger().error(f'{subscription.topic_name} ignored: {error}',
                                            throttle_duration_sec=1.0)
        return taken_any

    def _on_pose(self, data, received_ns):
        sec, nanosec, frame_id, values = POSE_STAMPED.decode(data)
        self.pose_link.add(sec * 1_000_000_000 + nanosec, received_ns)
        self._send(self.bridge.master_pose(frame_id, values[:3], values[3:], time.monotonic()))

    def _on_master_energy(self, data, _received_ns):
        sec, nanosec, _, energies = VECTOR3_STAMPED.decode(data)
        self.bridge.master_energy(energies[0], sec * 1_000_000_000 + nanosec)

    def _on_measured_cp(self, data, _received_ns):
        sec, nanosec, frame_id, values = POSE_STAMPED.decode(data)
        stamp = sec + 1e-9 * nanosec if sec or nanosec else None  # unstamped: when taken
        self._send(self.bridge.arm_pose(frame_id, values[:3], values[3:], time.monotonic(),
                                        stamp))

    def _on_measured_cf(self, data, _received_ns):
        _, _, frame_id, values = cdr.decode_wrench_stamped(data)
        self._send(self.bridge.ft_reading(frame_id, values, time.monotonic()))

    def _set_clutch(self, source, pressed):
        with self._lock:
            self._clutch_inputs[source] = pressed
            self._send(self.bridge.set_clutch(any(self._clutch_inputs.values())))

    def _on_clutch(self, msg):
        self._set_clutch('clutch', bool(msg.data))

    def _on_joy(self, msg):
        if self.clutch_button >= len(msg.buttons):
            self.get_logger().error(
                f'joy has {len(msg.buttons)} buttons, no clutch_button {self.clutch_button}',
                throttle_duration_sec=1.0)
            return
        self._set_clutch('joy', msg.buttons[self.clutch_button] == 1)

    def _on_enable(self, request, response):
        with self._lock:
            answer = (self.bridge.enable(time.monotonic(), self._base_rotation_from_tf)
                      if request.data else self.bridge.disable())
            self._send(answer.outputs)
        response.success = answer.refusal is None
        response.message = answer.refusal or answer.state
        self.get_logger().info(f'enable {request.data}: {response.message}')
        return response

    def _on_set_parameters(self, parameters):
        """Check a run-time set as at start-up, then hand the bridge its new settings."""
        try:
            changes = run_time_changes(PARAMETERS, parameters)
            if 'base_rotation' in changes and self._base_rotation_from_tf is not None:
                raise ParameterError('parameter base_rotation is taken from TF '
                                     '(base_rotation_from_tf)')
            with self._lock:
                self.bridge.configure(with_values(self.bridge.settings, changes),
                                      time.monotonic())
        except ParameterError as error:
            return SetParametersResult(successful=False, reason=str(error))
        except ValueError as error:  # what Settings' own check refuses, as at start-up
            return SetParametersResult(successful=False, reason=f'parameter {error}')
        if changes:
            self.get_logger().info('set ' + ', '.join(
                f'{name} {value}' for name, value in changes.items()))
        return SetParametersResult(successful=True)

    def _on_tare(self, _request, response):
        with self._lock:
            refusal = self.bridge.tare(time.monotonic())
        response.success = refusal is None
        response.message = refusal or 'F/T bias taken'
        return response

    # -- outputs ---------------------------------------------------------------------

    def _now(self):
        """Return this node's clock now as (sec, nanosec), for a header's stamp."""
        return divmod(self.get_clock().now().nanoseconds, 1_000_000_000)

    def _send(self, outputs):
        """Publish what the bridge returned: a refusal logged, state, command, wrench, energy."""
        if outputs.refusal is not None:
            self.get_logger().error(outputs.refusal, throttle_duration_sec=1.0)
        if outputs.state is not None:
            text = outputs.state.text
            self.state_pub.publish(String(data=text))
            if outputs.state.state is OperatingState.FAULT:
                self.get_logger().error(text)
        if outputs.command is not None:
            self.servo_pub.publish(self._servo_cdr.encode(*self._now(), outputs.command))
        if outputs.wrench is not None:
            self.wrench_pub.publish(self._wrench_cdr.encode(*self._now(), outputs.wrench))
        if outputs.slave_energy is not None:
            self.energy_pub.publish(self._energy_cdr.encode(*self._now(), outputs.slave_energy))
        if outputs.contact_model is not None:
            message = JointState(name=list(MODEL_FIELDS),
                                 position=outputs.contact_model.values())
            message.header.frame_id = self.bridge.settings.master_frame
            message.header.stamp = self.get_clock().now().to_msg()
            self.model_pub.publish(message)

    def _tick(self):
        """Enable at start once it can; send what the bridge's tick returns."""
        with self._lock:
            now = time.monotonic()
            if self.enable_at_start:
                answer = self.bridge.enable(now, self._base_rotation_from_tf)
                self._send(answer.outputs)
                if answer.refusal is None:
                    self.enable_at_start = False
                    self.get_logger().info(f'enabled at start: {answer.state}')
            self._send(self.bridge.tick(now))

    def _publish_diagnostics(self):
        with self._lock:
            level, message, values = bridge_diagnostics(self.bridge, self.scheduling,
                                                        self.pose_link.summary())
            array = DiagnosticArray(status=[DiagnosticStatus(
                name=f'{self.get_fully_qualified_name()}: teleoperation bridge',
                level=DIAGNOSTIC_LEVELS[level], message=message,
                values=[KeyValue(key=k, value=v) for k, v in values.items()])])
            array.header.stamp = self.get_clock().now().to_msg()
            self.diag_pub.publish(array)


def main(args=None):
    """Run the bridge until Ctrl-C or SIGTERM; exit 1 on a bad parameter."""
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)  # the input thread gets the GIL when it wakes
    return run_node(TeleopNode, 'kraft_master_teleop', __doc__.strip().splitlines()[0],
                    PARAMETERS, args)


if __name__ == '__main__':
    sys.exit(main())
