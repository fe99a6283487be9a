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
from kraft_master_driver.core.contact_model import ContactModel, NO_CONTACT
from kraft_master_driver.core.link_quality import LinkMonitor
from kraft_master_driver.core.rate_control import rate_command
from kraft_master_driver.core.wrench_admission import Rejection, WrenchAdmission
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
        self._node = node
        self._qos = state_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        # No QoS event handlers on the publishers: each one is work for every executor wake-up.
        self._quiet = quiet = PublisherEventCallbacks(use_default_callbacks=False)
        (self.joint_pub, self.pose_pub, self.pots_pub, self.energy_pub, self.diagnostics) = (
            node.create_publisher(msg_type, topic, state_qos, event_callbacks=quiet)
            for msg_type, topic in (
                (JointState, 'joint_states'), (PoseStamped, 'pose'), (JointState, 'pots'),
                # Energy in, out and dissipated at the master port (J), stamped when sent.
                (Vector3Stamped, 'master_energy'),
                # Where diagnostic_updater publishes them, whatever the namespace.
                (DiagnosticArray, '/diagnostics')))
        self.rate_pub = None  # rate_command: only once rate_command_enabled is true
        if config['rate_command_enabled']:
            self.advertise_rate_command()
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

    def advertise_rate_command(self):
        """
        Create rate_command's publisher, unless it exists (in the executor's thread).

        Never destroyed while the node runs: the loop thread may be publishing on it, and
        rclpy refuses a publish on a publisher destroyed under it. Set false again,
        rate_command_enabled leaves it advertised and silent.
        """
        if self.rate_pub is None:
            self.rate_pub = self._node.create_publisher(
                TwistStamped, 'rate_command', self._qos, event_callbacks=self._quiet)

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
        # rate_pub exists before rate_command_enabled is first true (advertise_rate_command).
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

    take() decodes every wrench that came and hands what the wrench admission
    (core/wrench_admission.py, every rule) made of it to the force reflection, and every slave
    energy to the master port. While the admission refuses the wrenches of several sources
    (wrench and servo_cf together) they are dropped and the force reflection holds none: zero
    torque. servo_cf (with crtk_names) is admitted as wrench is, and also takes an empty
    frame_id, which crtk_python_client sends, as the base frame.
    """

    def __init__(self, node, config, force, master_port, frames, model=None):
        """
        Subscribe on `node`; frames maps a wrench's frame_id to a force reflection frame.

        model: the contact model's side (core.force_mode.ModelFeedback), fed with
        contact_model and every message's delay; None (force_mode 'direct'): no contact_model.
        """
        self.force = force
        self.model = model
        self.master_port = master_port
        self.log = node.get_logger()
        self.slave_energy = (0.0, 0.0, 0.0)
        self.slave_link = LinkMonitor()
        self.wrench_taken_ns = None  # monotonic time the newest wrench was taken, any verdict
        self._wrench_sub = self._subscribe_wrench(node, 'wrench')
        self._servo_cf_sub = None
        if config['crtk_names']:
            self._servo_cf_sub = self._subscribe_wrench(node, 'servo_cf')
        self.admission = WrenchAdmission(
            frames, [sub.topic_name for sub in (self._wrench_sub, self._servo_cf_sub) if sub],
            config['allow_multiple_wrench_sources'], max_force=config['max_force'],
            max_moment=config['max_moment'], max_wrench_age=config['max_wrench_age'],
            max_stamp_skew=config['max_stamp_skew'])
        # All that came (the values are monotone; each one's delay counts, and one the next
        # overwrote would count as lost on the link).
        self._slave_energy_sub = ros_io.subscribe_raw(
            node, Vector3Stamped, 'slave_energy', self._on_slave_energy, 10)
        self._model_sub = None
        if model is not None:
            self._model_sub = node.create_subscription(
                JointState, 'contact_model', self._on_contact_model,
                QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))

    def _subscribe_wrench(self, node, topic):
        # Depth 1: only the newest wrench counts, and a slow cycle takes no stale backlog.
        return ros_io.subscribe_raw(node, WrenchStamped, topic, self._on_wrench, 1)

    def take(self):
        """Hand every wrench and slave energy that has arrived on, oldest first."""
        servo_cf = self._servo_cf_sub
        refused, sources_change = self.admission.count_sources(
            ros_io.publisher_count(self._wrench_sub, servo_cf))
        for data in ros_io.take_all(self._wrench_sub):
            self.wrench_taken_ns = time.monotonic_ns()
            if not refused:
                self._on_wrench(data)
        if servo_cf is not None:
            for data in ros_io.take_all(servo_cf):
                self.wrench_taken_ns = time.monotonic_ns()
                if not refused:
                    self._on_wrench(data, empty_is_base=True)
        if refused:
            self.force.clear()
        # Each one's delay to when DDS received it (system clock), not to this cycle's take.
        for data, received_ns in ros_io.take_all_received(self._slave_energy_sub):
            self._on_slave_energy(data, received_ns)
        if self._model_sub is not None:
            for message in ros_io.take_all(self._model_sub):
                self._on_contact_model(message)
        if sources_change is None:
            return
        if refused:  # rclpy keeps one severity per call site: a call for each
            self.log.warning(sources_change)
        else:
            self.log.info(sources_change)

    def _on_wrench(self, data, empty_is_base=False):
        """Decode one wrench (CDR bytes); hand what the admission made of it to the force."""
        try:
            sec, nanosec, frame_id, values = cdr.decode_wrench_stamped(data)
        except ValueError as error:
            self.force.hold(self.admission.malformed(str(error)))
            self.log.warning(f'wrench rejected, torques zeroed: {error}',
                             throttle_duration_sec=1.0)
            return
        stamp_ns, now_ns = sec * 1_000_000_000 + nanosec, time.time_ns()
        received_ns = time.monotonic_ns()
        admitted = self.admission.admit(values, frame_id, stamp_ns, received_ns, now_ns,
                                        empty_is_base)
        if self.model is not None and stamp_ns:
            self.model.delay((now_ns - stamp_ns) / 1e9, received_ns)
        self.force.hold(admitted)
        if isinstance(admitted, Rejection):
            self.log.warning(f'wrench rejected, torques zeroed: {admitted.text}',
                             throttle_duration_sec=1.0)

    def _on_slave_energy(self, data, received_ns):
        try:
            sec, nanosec, _, energies = VECTOR3_STAMPED.decode(data)
        except ValueError as error:
            self.log.warning(f'slave_energy ignored: {error}', throttle_duration_sec=1.0)
            return
        self.master_port.credit(energies[0], sec * 1_000_000_000 + nanosec)
        self.slave_energy = tuple(energies)
        self.slave_link.add(sec * 1_000_000_000 + nanosec, received_ns)

    def _on_contact_model(self, message):
        """Hand one contact_model on; a bad one takes the wall away, and is said why."""
        received_ns = time.monotonic_ns()
        stamp = message.header.stamp
        stamp_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        if stamp_ns:
            self.model.delay((time.time_ns() - stamp_ns) / 1e9, received_ns)
        try:
            model = ContactModel.from_values(message.name, message.position)
        except ValueError as error:
            self.model.take(NO_CONTACT, received_ns)
            self.log.warning(f'{error}: no wall', throttle_duration_sec=1.0)
            return
        self.model.take(model, received_ns)
