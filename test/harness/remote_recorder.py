# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Record teleoperation topics on one host (its namespace), print them as JSON when stopped.

Run inside a host of netns.TwoHosts: python remote_recorder.py TOPIC... (of measured_cp,
servo_cp, wrench, master_energy, slave_energy, diagnostics, joint_states, operating_state).
Prints 'ready' once subscribed and 'first TOPIC' when a topic's first message comes; on SIGINT
or SIGTERM prints one JSON line, {topic: [[monotonic receipt time, values...], ...]}
(diagnostics: [time, {key: value}]; joint_states: the efforts).
"""
import faulthandler
import json
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Vector3Stamped, WrenchStamped
from kraft_master_driver.nodes.node_process import SHUTDOWN_LIMIT_S
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String


def _xyz(v):
    return [v.x, v.y, v.z]


def _diagnostics(msg):
    return {item.key: item.value for status in msg.status for item in status.values}


TOPICS = {
    'measured_cp': (PoseStamped, lambda msg: _xyz(msg.pose.position)),
    'servo_cp': (PoseStamped, lambda msg: _xyz(msg.pose.position)),
    'pose': (PoseStamped, lambda msg: _xyz(msg.pose.position)),
    'wrench': (WrenchStamped, lambda msg: _xyz(msg.wrench.force)),
    'master_energy': (Vector3Stamped, lambda msg: _xyz(msg.vector)),
    'slave_energy': (Vector3Stamped, lambda msg: _xyz(msg.vector)),
    'diagnostics': (DiagnosticArray, lambda msg: [_diagnostics(msg)]),
    'joint_states': (JointState, lambda msg: list(msg.effort)),
    'operating_state': (String, lambda msg: [msg.data]),
}


def _recorder(topic, kept):
    def record(data):
        if not kept:
            print(f'first {topic}', flush=True)
        kept.append((time.monotonic(), data))
    return record


def main(topics):
    """Record until SIGINT or SIGTERM, then print the records; return 0."""
    rclpy.init()
    node = rclpy.create_node('remote_recorder')
    raw = {topic: [] for topic in topics}
    for topic in topics:
        # The bridge's states are few and each counts: best effort may drop one under load (the
        # DISABLED of a lost link was missing once, beside a busy loop per core).
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE
                         if topic == 'operating_state' else ReliabilityPolicy.BEST_EFFORT)
        # Raw: a callback only keeps the bytes (1 kHz topics cost little); decoded at the end.
        node.create_subscription(TOPICS[topic][0], topic, _recorder(topic, raw[topic]), qos,
                                 raw=True)
    print('ready', flush=True)
    try:
        rclpy.spin(node)  # rclpy turns SIGINT and SIGTERM into the end of the spin
    except (KeyboardInterrupt, ExternalShutdownException, RuntimeError):
        pass  # RuntimeError: the signal shut the context down while the spin built a wait set
    records = {topic: [[t, *TOPICS[topic][1](deserialize_message(data, TOPICS[topic][0]))]
                       for t, data in kept] for topic, kept in raw.items()}
    print(json.dumps(records), flush=True)
    # The nodes' own guard: a teardown stuck in Fast DDS ends the process, its stacks on stderr
    # (in a fresh clone's run one did not end within 60 s of SIGINT, where it was not known).
    faulthandler.dump_traceback_later(SHUTDOWN_LIMIT_S, exit=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
