# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_node: the ROS 2 driver of one Kraft Master hand controller.

One loop thread owns the device and the timing (wrenches in, torques out, pots in,
kinematics, publish); the rclpy executor spins in the main thread for services, parameters
and diagnostics. The core modules it uses import no rclpy.
"""
import operator
import os
import sys
import threading
import time
from typing import NamedTuple

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TwistStamped, Vector3Stamped, WrenchStamped
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration, CalibrationError
from kraft_master_driver.core.force_reflection import (
    BASE_FRAME, ForceReflection, rate_command, STALE, WRIST_FRAME)
from kraft_master_driver.core.loop_statistics import LoopStatistics, VelocityFilter
from kraft_master_driver.core.passivity import LinkMonitor, MasterPort
from kraft_master_driver.link import cdr
from kraft_master_driver.link.device import KmcDevice
from kraft_master_driver.link.protocol import ERROR_KINDS
from kraft_master_driver.nodes.driver_parameters import PARAMETERS, SIM_PORT
from kraft_master_driver.nodes.lifecycle import run_node
from kraft_master_driver.nodes.parameters import (
    check_value, declare_parameters, ParameterError)
from kraft_master_driver.nodes.ros_helpers import GIL_SWITCH_INTERVAL_S, TakenByLoopThread
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

ZERO_TORQUES = (0.0,) * kinematics.DRIVEN_JOINTS
POT_NAMES = [f'pot{i}' for i in range(1, 7)]
VECTOR3_STAMPED = cdr.StampedDoublesDecoder('Vector3Stamped', 3)


def _milliseconds(name, median_p99_max):
    return {f'{name} {label} (ms)': f'{1e3 * seconds:.3f}'
            for label, seconds in zip(('median', 'p99', 'max'), median_p99_max)}


class Estimate(NamedTuple):
    """
    What one pot frame tells, in plain floats.

    theta and velocity (6 each), pose (0T6 row by row, 16), its rotation (3 rows of 3) and
    the Jacobian (6 rows of 6).
    """

    theta: list
    velocity: list
    pose: tuple
    rotation: tuple
    jacobian: list


class KraftMasterNode(Node):
    """Publishes the hand controller's state and reflects task wrenches as joint torques."""

    def __init__(self, params_files=(), **kwargs):
        """Declare and check parameters, open the device and start the loop thread."""
        super().__init__('kraft_master_node', **kwargs)
        self.config = declare_parameters(self, PARAMETERS, params_files)
        self.arm = self.config['arm']
        self.lengths = kinematics.LinkLengths(*self.config['link_lengths'])
        self.calibration = self._calibration()
        self.joint_names = [self.config['joint_prefix'] + n for n in kinematics.JOINT_NAMES]
        self.frames = {self.config['base_frame']: BASE_FRAME,
                       self.config['wrist_frame']: WRIST_FRAME}
        self.force = ForceReflection(
            force_scale=self.config['force_scale'],
            torque_limits=tuple(self.config['torque_limits']),
            coupling=self.config['coupling'],
            wrench_timeout=self.config['wrench_timeout'],
            max_force=self.config['max_force'], max_moment=self.config['max_moment'],
            centre_stiffness=tuple(self.config['centre_stiffness']),
            centre_damping=tuple(self.config['centre_damping']))
        self.force.enabled = self.config['force_enabled_at_start']
        self.master_port = MasterPort()
        self.master_port.enabled = self.config['passivity']
        self.slave_link = LinkMonitor()
        self.slave_energy = (0.0, 0.0, 0.0)

        state_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        # No QoS event handlers on the publishers: each one is work for every executor wake-up.
        quiet = PublisherEventCallbacks(use_default_callbacks=False)
        # Diagnostics go where diagnostic_updater publishes them, whatever the namespace.
        self.joint_pub, self.pose_pub, self.pots_pub, self.rate_pub, self.diag_pub = (
            self.create_publisher(msg_type, topic, state_qos, event_callbacks=quiet)
            for msg_type, topic in ((JointState, 'joint_states'), (PoseStamped, 'pose'),
                                    (JointState, 'pots'), (TwistStamped, 'rate_command'),
                                    (DiagnosticArray, '/diagnostics')))
        self._make_encoders()
        self._wrench_sub = self.create_subscription(
            WrenchStamped, 'wrench', self._on_wrench,
            # Depth 1: only the newest wrench counts, and a slow cycle takes no stale backlog.
            QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT), raw=True,
            callback_group=TakenByLoopThread(),
            event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))
        # Energy in, out and dissipated at each port (J), each stamped when sent.
        self.energy_pub = self.create_publisher(Vector3Stamped, 'master_energy', state_qos,
                                                event_callbacks=quiet)
        # Taken by the loop like the wrenches, all that came (the values are monotone; each
        # one's delay counts, and one the next overwrote would count as lost on the link).
        self._slave_energy_sub = self.create_subscription(
            Vector3Stamped, 'slave_energy', self._on_slave_energy,
            QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT), raw=True,
            callback_group=TakenByLoopThread(),
            event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))
        self.create_service(SetBool, 'enable_force', self._on_enable_force)
        self.create_service(Trigger, 'set_center', self._on_set_center)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.create_timer(1.0, self._publish_diagnostics)

        self.simulator = None
        port = self.config['port']
        if port == SIM_PORT:
            port = self._start_simulator()
        self.device = KmcDevice(
            port, baudrate=self.config['baud'], codec=self.config['codec'],
            reply_timeout=self.config['reply_timeout'],
            torque_scale=tuple(self.config['torque_scale']),
            torque_limit=tuple(self.config['torque_command_limit']),
            low_latency=self.config['low_latency'])
        self.device.open()
        if self.device.link_up and self.device.stats['low_latency_failures']:
            self.get_logger().warning(self.device.last_error)
        self._warn_if_wire_limited()

        self.loop = LoopStatistics()
        self.loop_scheduler = 'normal'
        self._replies_missing = 0
        # Failed opens at which a down link is reported next (the first is reported below).
        self._link_report_at = 0 if self.device.link_up else 2
        self._failed_opens_when_up = 0
        self._wrench_sources = 0
        self._wrenches_refused = False
        self._last_force_state = None
        self._errors_reported = {}
        self.velocity = VelocityFilter(self.config['velocity_cutoff_hz'])
        self.output = None
        self.pose_entries = None  # 0T6 of the newest frame, 16 floats row by row
        self.cartesian_velocity = None
        self._theta = None  # joint angles of the last frame, for the master port's work
        self.centre = None
        self._running = True
        # Not a daemon: the interpreter waits for the loop to zero the torques on its way out,
        # even when a signal ends the process before this constructor returns.
        self._thread = threading.Thread(target=self._run, name='kraft_master_loop')
        self._thread.start()
        force = 'enabled' if self.force.enabled else 'disabled (call enable_force)'
        if self.device.link_up:
            self.get_logger().info(
                f'{self.arm} Kraft Master on {self.config["port"]} at '
                f'{self.config["loop_rate_hz"]:g} Hz; force output {force}')
        else:
            self.get_logger().warning(
                f'{self.arm} Kraft Master on {self.config["port"]}: {self._link_state()}; '
                'retrying')

    # -- set-up --------------------------------------------------------------------------

    def _calibration(self):
        calibration = {key.split('.', 1)[1]: value for key, value in self.config.items()
                       if key.startswith('calibration.')}
        given = [key for key in calibration if f'calibration.{key}' in self._parameter_overrides]
        if given and len(given) < len(calibration):
            missing = sorted(set(calibration) - set(given))
            raise ParameterError(
                f'parameter calibration.{missing[0]}: missing; a calibration must give all of '
                f'{", ".join("calibration." + key for key in calibration)}')
        try:
            return ArmCalibration.from_parameters(self.arm, calibration, 'parameters')
        except CalibrationError as error:
            raise ParameterError(str(error)) from None

    def _start_simulator(self):
        from kraft_master_driver.simulation.simulator import SimulatedKraftMaster
        self.simulator = SimulatedKraftMaster(
            arm=self.arm, calibration=self.calibration,
            torque_scale=tuple(self.config['torque_scale']),
            coupling=self.config['coupling'], operator=self.config['sim_operator'],
            pot_noise_counts=self.config['sim_noise_counts'])
        path = self.simulator.start()
        self.get_logger().info(f'simulated hand controller on {path}')
        return path

    def _warn_if_wire_limited(self):
        if self.simulator is not None:
            return
        wire_rate = self.device.wire_limited_rate()
        if wire_rate < self.config['loop_rate_hz']:
            self.get_logger().warning(
                f'at {self.config["baud"]} baud the link carries at most {wire_rate:.0f} '
                f'cycles/s, below loop_rate_hz {self.config["loop_rate_hz"]:g}')

    # -- the loop thread -----------------------------------------------------------------

    def _raise_priority(self):
        """Give the loop thread real-time priority if asked and allowed; say what happened."""
        priority = self.config['loop_priority']
        if not priority:
            return
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except (OSError, AttributeError) as error:
            self.loop_scheduler = f'normal ({error})'
            self.get_logger().warning(
                f'loop_priority {priority}: real-time scheduling refused ({error}); the loop '
                'runs at normal priority (allow it with an rtprio limit or CAP_SYS_NICE, or '
                'set loop_priority 0 to silence this)')
            return
        self.loop_scheduler = f'SCHED_FIFO {priority}'

    def _run(self):
        """Run the loop at its priority; however it ends, zero the torques and close."""
        self._raise_priority()
        try:
            self._cycle_until_stopped()
        finally:
            self.device.close()

    def _cycle_until_stopped(self):
        """
        Pace the device cycles: command out at each deadline, reply in, state published.

        A late cycle sends its next command as soon as the reply is estimated and publishes
        while that command is on the wire, so a wire-limited link is never idle for the
        publishing. Ends when stop() is called or the ROS context shuts down (a signal).
        """
        period_ns = int(1e9 / self.config['loop_rate_hz'])
        cpu = time.thread_time_ns
        deadline = time.monotonic_ns()
        self.loop.record_start(deadline)
        sent = self._send_torques(None)
        while self._running and self.context.ok():
            try:
                c0 = cpu()
                result = self.device.receive() if sent else None
                c1 = cpu()
                estimate = None
                if result is None:
                    self.velocity.reset()
                    self._theta = None
                    self._warn_no_reply()
                else:
                    if self._replies_missing:
                        self._replies_missing = 0
                        self._link_report_at = 0
                        self._failed_opens_when_up = self.device.stats['failed_opens']
                        self.get_logger().info('the device answers again',
                                               throttle_duration_sec=1.0)
                    self.loop.round_trips.add(int(result.round_trip_s * 1e9))
                    estimate = self._estimate(result)
                self.loop.add_cpu(link=c1 - c0, kinematics=cpu() - c1)
                deadline += period_ns
                now = time.monotonic_ns()
                late = now >= deadline
                if late:
                    # Run at once to catch up; skip whole periods that cannot be caught up.
                    self.loop.late += 1
                    skipped = (now - deadline) // period_ns
                    self.loop.missed += skipped
                    deadline += skipped * period_ns
                    self.loop.record_start(now)
                    sent = self._send_torques(estimate)
                if estimate is not None and self.loop.frames % self.config[
                        'publish_decimation'] == 0:
                    c2 = cpu()
                    self._publish_state(result, estimate)
                    self.loop.published += 1
                    self.loop.add_cpu(publish=cpu() - c2)
                if not late:
                    time.sleep(max(0, deadline - time.monotonic_ns()) / 1e9)
                    self.loop.record_start(time.monotonic_ns())
                    sent = self._send_torques(estimate)
            except Exception as error:  # noqa: B902 - any fault must end in zero torque
                if not self._running or not self.context.ok():
                    break
                sent = self.device.send(ZERO_TORQUES)
                self.loop.internal_errors += 1
                self.get_logger().error(f'cycle failed, torques zeroed: {error!r}',
                                        throttle_duration_sec=1.0)
                time.sleep(period_ns / 1e9)  # no busy loop at real-time priority if it recurs
                deadline = time.monotonic_ns()

    def _send_torques(self, estimate):
        """Take the wrenches that came, work out the torques and send them; True if sent."""
        c0 = time.thread_time_ns()
        self._take_wrenches()
        output = None
        if estimate is None:
            self.master_port.idle(time.monotonic_ns())
        else:
            output = self.force.compute(
                estimate.rotation, estimate.jacobian, time.monotonic_ns(),
                pose=None if self.centre is None else self._pose(), centre=self.centre,
                cartesian_velocity=self.cartesian_velocity, port=self.master_port)
            if output.state == STALE and self._last_force_state != STALE:
                self.get_logger().warning(
                    f'no wrench for {self.config["wrench_timeout"]:g} s (wrench_timeout): '
                    'torques zeroed', throttle_duration_sec=1.0)
            self._last_force_state = output.state
        self.output = output
        c1 = time.thread_time_ns()
        sent = self.device.send(ZERO_TORQUES if output is None else output.actuator)
        self.loop.add_cpu(kinematics=c1 - c0, link=time.thread_time_ns() - c1)
        return sent

    def _take_wrenches(self):
        """
        Hand every wrench that has arrived to _on_wrench, oldest first.

        While more than one publisher is matched (and allow_multiple_wrench_sources is false)
        the wrenches are dropped and the force reflection holds none: zero torque.
        """
        handle = self._wrench_sub.handle
        with handle:
            sources = handle.get_publisher_count()
            refused = sources > 1 and not self.config['allow_multiple_wrench_sources']
            while (taken := handle.take_message(WrenchStamped, True)) is not None:
                if not refused:
                    self._on_wrench(taken[0])
        if refused:
            self.force.clear()
        handle = self._slave_energy_sub.handle
        with handle:
            while (taken := handle.take_message(Vector3Stamped, True)) is not None:
                # Its delay to when DDS received it (system clock), not to this cycle's take.
                self._on_slave_energy(taken[0],
                                      taken[1]['received_timestamp'] or time.time_ns())
        if sources != self._wrench_sources:
            self._wrench_sources = sources
            if refused:
                self.get_logger().warning(f'{self._several_sources()}: torques zeroed')
            elif self._wrenches_refused:
                self.get_logger().info(f'{sources} publisher(s) on wrench: wrenches accepted')
            self._wrenches_refused = refused

    def _on_wrench(self, data):
        """Check one wrench (CDR bytes) and hand it to the force reflection."""
        try:
            sec, nanosec, frame_id, values = cdr.decode_wrench_stamped(data)
        except ValueError as error:
            self.force.reject('malformed')
            self.get_logger().warning(f'wrench rejected, torques zeroed: {error}',
                                      throttle_duration_sec=1.0)
            return
        frame = self.frames.get(frame_id)
        tag = sec * 1_000_000_000 + nanosec
        skew = time.time_ns() - tag
        if tag and abs(skew) > self.config['max_stamp_skew'] * 1e9:
            self.force.reject('bad_timestamp', tag)
            self.get_logger().warning(
                f'wrench rejected, torques zeroed: its stamp is {skew / 1e9:+.3f} s off this '
                f'clock (max_stamp_skew {self.config["max_stamp_skew"]:g} s)',
                throttle_duration_sec=1.0)
            return
        accepted, reason = self.force.submit(values, frame, time.monotonic_ns(), tag)
        if frame is None:
            reason = (f'frame_id {frame_id!r} is not one of '
                      f'{" or ".join(repr(f) for f in self.frames)}')
        if not accepted:
            self.get_logger().warning(f'wrench rejected, torques zeroed: {reason}',
                                      throttle_duration_sec=1.0)

    def _warn_no_reply(self):
        """Say why this cycle got no pot frame; its torques, and the next cycle's, are zero."""
        self._replies_missing += 1
        if self.device.link_up:
            self.get_logger().warning(
                f'no reply within reply_timeout {self.config["reply_timeout"]:g} s '
                f'({self._replies_missing} in a row): torques zeroed', throttle_duration_sec=1.0)
            return
        # Reported at the fault, then after 1, 2, 4, 8... failed reopens: less often as the
        # backoff grows.
        attempts = self.device.stats['failed_opens'] - self._failed_opens_when_up
        if attempts >= self._link_report_at:
            self._link_report_at = max(2 * attempts, 1)
            tried = f' ({attempts} attempts)' if attempts else ''
            self.get_logger().warning(f'{self._link_state()}{tried}: torques zero')

    def _link_state(self):
        """Return what the driver waits for and why while the link is down."""
        reason = self.device.last_error.removeprefix(f'{self.device.port}: ')
        if self.loop.frames:
            return f'link down: {reason}; reconnecting'
        return f'waiting for the device: {reason}'

    def _several_sources(self):
        """Say why wrenches are refused while several publishers are matched."""
        return (f'{self._wrench_sources} publishers on {self._wrench_sub.topic_name}, only one '
                'wrench source is allowed (allow_multiple_wrench_sources)')

    def _estimate(self, result):
        """Joint angles, velocity, wrist pose and Jacobian of one pot frame, in floats."""
        theta = self.calibration.frame_to_joints(result.frame.pots)
        pose, jacobian = kinematics.forward_and_jacobian_entries(theta, self.arm, self.lengths)
        previous, self._theta = self._theta, theta
        velocity = self.velocity.update(theta, result.receive_ns)
        jacobian = [jacobian[row:row + 6] for row in range(0, 36, 6)]
        self.cartesian_velocity = [sum(map(operator.mul, row, velocity)) for row in jacobian]
        if previous is not None:
            step = [now - before for now, before in zip(theta, previous)]
            self.master_port.moved([sum(map(operator.mul, row, step)) for row in jacobian])
        self.pose_entries = pose
        self.loop.frames += 1
        return Estimate(theta, velocity, pose, (pose[0:3], pose[4:7], pose[8:11]), jacobian)

    def _pose(self):
        """Return the newest wrist pose 0T6 as a new 4x4 array, None before the first frame."""
        entries = self.pose_entries
        return None if entries is None else np.array(entries).reshape(4, 4)

    def _effort(self, actuator_nm):
        """Joint torques th1..th6 (N*m) that the torques sent amount to; th6 has no motor."""
        torques = [*actuator_nm, 0.0]
        if self.config['coupling'] == 'actuator':
            torques[1] += torques[2]  # kinematics.joint_torques_from_actuator, inlined
        return torques

    def _make_encoders(self):
        """Lay out the published messages once; each cycle packs only its values."""
        base = self.config['base_frame']
        self._joint_cdr = cdr.JointStateEncoder(base, self.joint_names, (6, 6, 6))
        self._pose_cdr = cdr.StampedDoublesEncoder(base, 7)
        self._pots_cdr = cdr.JointStateEncoder(base, POT_NAMES, (6, 0, 0))
        self._twist_cdr = cdr.StampedDoublesEncoder(base, 6)
        self._energy_cdr = cdr.StampedDoublesEncoder(base, 3)

    def _publish_state(self, result, estimate):
        sec, nanosec = divmod(result.receive_ns, 1_000_000_000)
        self.joint_pub.publish(self._joint_cdr.encode(
            sec, nanosec, estimate.theta, estimate.velocity, self._effort(result.commanded_nm)))
        pose = estimate.pose
        self.pose_pub.publish(self._pose_cdr.encode(
            sec, nanosec, (pose[3], pose[7], pose[11],
                           *kinematics.rotation_to_quaternion(estimate.rotation))))
        self.pots_pub.publish(self._pots_cdr.encode(
            sec, nanosec, [float(count) for count in result.frame.pots], (), ()))
        port = self.master_port
        self.energy_pub.publish(self._energy_cdr.encode(
            sec, nanosec, (port.energy_in, port.energy_out, port.dissipated)))
        if self.config['rate_command_enabled'] and self.centre is not None:
            linear, angular = rate_command(self._pose(), self.centre, *self.config['rate_gain'])
            self.rate_pub.publish(self._twist_cdr.encode(
                sec, nanosec, linear.tolist() + angular.tolist()))

    # -- executor callbacks --------------------------------------------------------------

    def _on_enable_force(self, request, response):
        self.force.enabled = bool(request.data)
        if not request.data:
            self.force.clear()
        response.success = True
        response.message = 'force output ' + ('enabled' if request.data else 'disabled')
        self.get_logger().info(response.message)
        return response

    def _on_slave_energy(self, data, received_ns):
        try:
            sec, nanosec, _, energies = VECTOR3_STAMPED.decode(data)
        except ValueError as error:
            self.get_logger().warning(f'slave_energy ignored: {error}', throttle_duration_sec=1.0)
            return
        self.master_port.credit(energies[0])
        self.slave_energy = tuple(energies)
        self.slave_link.add(sec * 1_000_000_000 + nanosec, received_ns)

    def _on_set_center(self, request, response):
        pose = self._pose()
        response.success = pose is not None
        if pose is None:
            response.message = 'no pose yet: the device has not answered'
        else:
            self.centre = pose
            x, y, z = pose[:3, 3]
            response.message = f'centre set at ({x:.4f}, {y:.4f}, {z:.4f}) m'
        return response

    def _on_set_parameters(self, parameters):
        changes = {}
        for parameter in parameters:
            spec = PARAMETERS.get(parameter.name)
            if spec is None:
                continue
            if spec.read_only:
                return SetParametersResult(
                    successful=False, reason=f'parameter {parameter.name} is read-only')
            try:
                changes[parameter.name] = check_value(PARAMETERS, parameter.name, parameter.value)
            except ParameterError as error:
                return SetParametersResult(successful=False, reason=str(error))
        force_keys = {'force_scale', 'wrench_timeout', 'max_force', 'max_moment',
                      'torque_limits', 'centre_stiffness', 'centre_damping'}
        try:
            self.force.configure(**{key: tuple(value) if isinstance(value, list) else value
                                    for key, value in changes.items() if key in force_keys})
        except ValueError as error:
            return SetParametersResult(successful=False, reason=str(error))
        if 'passivity' in changes:
            self.master_port.enabled = changes['passivity']
        if 'velocity_cutoff_hz' in changes:
            self.velocity.cutoff_hz = changes['velocity_cutoff_hz']
        self.config.update(changes)
        return SetParametersResult(successful=True)

    def _warn_link_errors(self, device_stats):
        """Name the decoder errors of the last diagnostics period, if there were any."""
        grown = {kind: device_stats[kind] - self._errors_reported.get(kind, 0)
                 for kind in ERROR_KINDS}
        self._errors_reported = {kind: device_stats[kind] for kind in ERROR_KINDS}
        if any(grown.values()):
            self.get_logger().warning(
                'bad bytes from the device, frames dropped: ' + ', '.join(
                    f'{kind} +{count}' for kind, count in grown.items() if count))

    def _publish_diagnostics(self):
        period = self.loop.periods.percentiles_s()
        round_trip = self.loop.round_trips.percentiles_s()
        device = self.device.stats
        self._warn_link_errors(device)
        link_ok = self.device.link_up
        values = {
            'loop rate (Hz)': f'{self.loop.rate_hz():.1f}',
            **_milliseconds('period', period),
            **_milliseconds('link round trip', round_trip),
            'pot frames received': str(self.loop.frames),
            'pot frames published': str(self.loop.published),
            'late cycles': str(self.loop.late),
            'missed cycles': str(self.loop.missed),
            **{f'cpu per cycle {phase} (us)': f'{1e6 * seconds:.1f}'
               for phase, seconds in self.loop.cpu_per_cycle().items()},
            'internal errors': str(self.loop.internal_errors),
            'loop scheduler': self.loop_scheduler,
            'force output': 'enabled' if self.force.enabled else 'disabled',
            'force state': self.output.state if self.output else 'no_state',
            'wrench sources': str(self._wrench_sources),
            'calibration': self.calibration.source,
            'port': self.config['port'],
        }
        values.update({f'link {key}': str(value) for key, value in device.items()})
        values.update({f'force {key}': str(value) for key, value in self.force.counters.items()})
        level, message = DiagnosticStatus.OK, 'running'
        if not link_ok:
            level, message = DiagnosticStatus.ERROR, self._link_state()
        elif self._wrench_sources > 1 and not self.config['allow_multiple_wrench_sources']:
            level, message = DiagnosticStatus.WARN, f'torques zero: {self._several_sources()}'
            values['force state'] = 'several_sources'
        values.update(self._passivity_values())
        port = self.config['port']
        status = DiagnosticStatus(
            name=f'{self.get_fully_qualified_name()}: {self.arm} Kraft Master',
            hardware_id='simulated KMC 9100' if port == SIM_PORT else f'KMC 9100 on {port}',
            level=level, message=message,
            values=[KeyValue(key=k, value=v) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(array)

    def _passivity_values(self):
        """Diagnostics of the channel: passivity, energies at each port, delay and loss."""
        port = self.master_port
        values = {'passivity': 'on' if port.enabled else 'off'}
        for side, (energy_in, energy_out, dissipated) in (
                ('master', (port.energy_in, port.energy_out, port.dissipated)),
                ('slave', self.slave_energy)):
            values.update({f'{side} energy in (J)': f'{energy_in:.4f}',
                           f'{side} energy out (J)': f'{energy_out:.4f}',
                           f'{side} energy dissipated (J)': f'{dissipated:.4f}'})
        values['master energy observed (J)'] = f'{port.observed:.4f}'
        link = self.slave_link.summary()
        if link is not None:
            values.update(_milliseconds('slave to master delay', link[:3]))
            values['slave to master loss (%)'] = f'{100.0 * link[3]:.1f}'
        return values

    # -- shutdown ------------------------------------------------------------------------

    def destroy_node(self):
        """Stop the device first (zero torques), then the node."""
        self.stop()
        super().destroy_node()

    def stop(self):
        """Stop the loop thread, write zero torques, close the port and the simulator."""
        self._running = False
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self.device.close()
        if self.simulator is not None:
            self.simulator.stop()


def main(args=None):
    """Run the driver until Ctrl-C or SIGTERM; exit 1 on a bad parameter."""
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    return run_node(KraftMasterNode, 'kraft_master_node', __doc__.strip().splitlines()[0],
                    PARAMETERS, args)


if __name__ == '__main__':
    sys.exit(main())
