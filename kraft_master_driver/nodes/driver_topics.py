# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The topics of kraft_master_node: the state it publishes and the inputs its loop takes.

Both handle CDR bytes themselves (nodes/cdr.py): the loop thread packs and unpacks only values,
with the messages' layout worked out once. With crtk_names, the same state also goes out under
CRTK's names (measured_js, measured_cp: the same bytes, published twice) and servo_cf is a
second name of the wrench input; without it, no CRTK topic exists and the cycle does no more.
"""
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, TwistStamped, Vector3Stamped, WrenchStamped
from kraft_master_driver.core import rotations
from kraft_master_driver.core.link_quality import LinkMonitor
from kraft_master_driver.core.rate_control import rate_command
from kraft_master_driver.nodes import cdr
from kraft_master_driver.nodes import ros_io
import numpy as np
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

POT_NAMES = [f'pot{i}' for i in range(1, 7)]
VECTOR3_STAMPED = cdr.StampedDoublesDecoder('Vector3Stamped', 3)


class StateTopics:
    """The driver's publishers: its state each published cycle, and its diagnostics."""

    def __init__(self, node, config, joint_names, master_port):
        """Create the publishers on `node`; config is the node's (live) parameter values."""
        self.config = config
        self.master_port = master_port
        state_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        # No QoS event handlers on the publishers: each one is work for every executor wake-up.
        quiet = PublisherEventCallbacks(use_default_callbacks=False)
        (self.joint_pub, self.pose_pub, self.pots_pub, self.rate_pub, self.energy_pub,
         self.diagnostics) = (
            node.create_publisher(msg_type, topic, state_qos, event_callbacks=quiet)
            for msg_type, topic in (
                (JointState, 'joint_states'), (PoseStamped, 'pose'), (JointState, 'pots'),
                (TwistStamped, 'rate_command'),
                # Energy in, out and dissipated at the master port (J), stamped when sent.
                (Vector3Stamped, 'master_energy'),
                # Where diagnostic_updater publishes them, whatever the namespace.
                (DiagnosticArray, '/diagnostics')))
        # CRTK's names for the same state (crtk_names), else nothing is created or published.
        self.crtk_pubs = None
        if config['crtk_names']:
            self.crtk_pubs = tuple(
                node.create_publisher(msg_type, topic, state_qos, event_callbacks=quiet)
                for msg_type, topic in ((JointState, 'measured_js'),
                                        (PoseStamped, 'measured_cp')))
        # The messages' layout, once; each cycle packs only its values.
        base = config['base_frame']
        self._joint_cdr = cdr.JointStateEncoder(base, joint_names, (6, 6, 6))
        self._pose_cdr = cdr.StampedDoublesEncoder(base, 7)
        self._pots_cdr = cdr.JointStateEncoder(base, POT_NAMES, (6, 0, 0))
        self._twist_cdr = cdr.StampedDoublesEncoder(base, 6)
        self._energy_cdr = cdr.StampedDoublesEncoder(base, 3)

    def publish(self, result, estimate, centre):
        """Publish one cycle: joint state, pose, pots, energies, rate command if asked."""
        sec, nanosec = divmod(result.receive_ns, 1_000_000_000)
        joint_state = self._joint_cdr.encode(
            sec, nanosec, estimate.theta, estimate.velocity, self._effort(result.commanded_nm))
        self.joint_pub.publish(joint_state)
        pose = estimate.pose
        pose_stamped = self._pose_cdr.encode(
            sec, nanosec, (pose[3], pose[7], pose[11],
                           *rotations.rotation_to_quaternion(estimate.rotation)))
        self.pose_pub.publish(pose_stamped)
        if self.crtk_pubs is not None:
            self.crtk_pubs[0].publish(joint_state)
            self.crtk_pubs[1].publish(pose_stamped)
        self.pots_pub.publish(self._pots_cdr.encode(
            sec, nanosec, [float(count) for count in result.frame.pots], (), ()))
        port = self.master_port
        self.energy_pub.publish(self._energy_cdr.encode(
            sec, nanosec, (port.energy_in, port.energy_out, port.dissipated)))
        if self.config['rate_command_enabled'] and centre is not None:
            linear, angular = rate_command(np.array(pose).reshape(4, 4), centre,
                                           *self.config['rate_gain'])
            self.rate_pub.publish(self._twist_cdr.encode(
                sec, nanosec, linear.tolist() + angular.tolist()))

    def _effort(self, actuator_nm):
        """Joint torques th1..th6 (N*m) that the torques sent amount to; th6 has no motor."""
        torques = [*actuator_nm, 0.0]
        if self.config['coupling'] == 'actuator':
            torques[1] += torques[2]  # kinematics.joint_torques_from_actuator, inlined
        return torques


class InputTopics:
    """
    The wrench and slave_energy subscriptions, taken raw by the loop thread (nodes/ros_io.py).

    take() hands every wrench that came to the force reflection and every slave energy to the
    master port. While more than one publisher is matched on wrench and servo_cf together (and
    allow_multiple_wrench_sources is false) the wrenches are dropped and the force reflection
    holds none: zero torque. servo_cf (with crtk_names) is checked as wrench is, and also takes
    an empty frame_id, which crtk_python_client sends, as the base frame.
    """

    def __init__(self, node, config, force, master_port, frames):
        """Subscribe on `node`; frames maps a wrench's frame_id to a force reflection frame."""
        self.config = config
        self.force = force
        self.master_port = master_port
        self.frames = frames
        self.log = node.get_logger()
        self.slave_energy = (0.0, 0.0, 0.0)
        self.slave_link = LinkMonitor()
        self.wrench_sources = 0
        self._wrenches_refused = False
        self._wrench_sub = self._subscribe_wrench(node, 'wrench')
        self._servo_cf_sub = None
        if config['crtk_names']:
            self._servo_cf_sub = self._subscribe_wrench(node, 'servo_cf')
            self.crtk_frames = {**frames, '': frames[config['base_frame']]}
        # All that came (the values are monotone; each one's delay counts, and one the next
        # overwrote would count as lost on the link).
        self._slave_energy_sub = ros_io.subscribe_raw(
            node, Vector3Stamped, 'slave_energy', self._on_slave_energy, 10)

    def _subscribe_wrench(self, node, topic):
        # Depth 1: only the newest wrench counts, and a slow cycle takes no stale backlog.
        return ros_io.subscribe_raw(node, WrenchStamped, topic, self._on_wrench, 1)

    @property
    def sources_refused(self):
        """Whether wrenches are refused now: several publishers matched, and not allowed."""
        return self.wrench_sources > 1 and not self.config['allow_multiple_wrench_sources']

    def several_sources(self):
        """Say why wrenches are refused while several publishers are matched."""
        topics = self._wrench_sub.topic_name
        if self._servo_cf_sub is not None:
            topics += f' and {self._servo_cf_sub.topic_name}'
        return (f'{self.wrench_sources} publishers on {topics}, only one '
                'wrench source is allowed (allow_multiple_wrench_sources)')

    def take(self):
        """Hand every wrench and slave energy that has arrived on, oldest first."""
        servo_cf = self._servo_cf_sub
        sources = ros_io.publisher_count(self._wrench_sub, servo_cf)
        refused = sources > 1 and not self.config['allow_multiple_wrench_sources']
        for data in ros_io.take_all(self._wrench_sub):
            if not refused:
                self._on_wrench(data)
        if servo_cf is not None:
            for data in ros_io.take_all(servo_cf):
                if not refused:
                    self._on_wrench(data, self.crtk_frames)
        if refused:
            self.force.clear()
        # Each one's delay to when DDS received it (system clock), not to this cycle's take.
        for data, received_ns in ros_io.take_all_received(self._slave_energy_sub):
            self._on_slave_energy(data, received_ns)
        if sources != self.wrench_sources:
            self.wrench_sources = sources
            if refused:
                self.log.warning(f'{self.several_sources()}: torques zeroed')
            elif self._wrenches_refused:
                self.log.info(f'{sources} publisher(s) on wrench: wrenches accepted')
            self._wrenches_refused = refused

    def _on_wrench(self, data, frames=None):
        """Check one wrench (CDR bytes) and hand it to the force reflection."""
        frames = self.frames if frames is None else frames
        try:
            sec, nanosec, frame_id, values = cdr.decode_wrench_stamped(data)
        except ValueError as error:
            self.force.reject('malformed')
            self.log.warning(f'wrench rejected, torques zeroed: {error}',
                             throttle_duration_sec=1.0)
            return
        frame = frames.get(frame_id)
        tag = sec * 1_000_000_000 + nanosec
        skew = time.time_ns() - tag
        if tag and abs(skew) > self.config['max_stamp_skew'] * 1e9:
            self.force.reject('bad_timestamp', tag)
            self.log.warning(
                f'wrench rejected, torques zeroed: its stamp is {skew / 1e9:+.3f} s off this '
                f'clock (max_stamp_skew {self.config["max_stamp_skew"]:g} s)',
                throttle_duration_sec=1.0)
            return
        accepted, reason = self.force.submit(values, frame, time.monotonic_ns(), tag,
                                             stamp_age_ns=skew if tag else None)
        if frame is None:
            reason = (f'frame_id {frame_id!r} is not one of '
                      f'{" or ".join(repr(f) for f in frames)}')
        if not accepted:
            self.log.warning(f'wrench rejected, torques zeroed: {reason}',
                             throttle_duration_sec=1.0)

    def _on_slave_energy(self, data, received_ns):
        try:
            sec, nanosec, _, energies = VECTOR3_STAMPED.decode(data)
        except ValueError as error:
            self.log.warning(f'slave_energy ignored: {error}', throttle_duration_sec=1.0)
            return
        self.master_port.credit(energies[0])
        self.slave_energy = tuple(energies)
        self.slave_link.add(sec * 1_000_000_000 + nanosec, received_ns)
