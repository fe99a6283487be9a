# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Record teleoperation topics on one host (its namespace), print them as JSON when stopped.

Run inside a host of netns.TwoHosts: python remote_recorder.py TOPIC... (of slave_pose,
wrench, master_energy, slave_energy, diagnostics). Prints 'ready' once subscribed and
'first TOPIC' when a topic's first message comes; on SIGINT or SIGTERM prints one JSON line,
{topic: [[monotonic receipt time, values...], ...]} (diagnostics: [time, {key: value}]).
"""
import json
import signal
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Vector3Stamped, WrenchStamped
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy


def _xyz(v):
    return [v.x, v.y, v.z]


def _diagnostics(msg):
    return {item.key: item.value for status in msg.status for item in status.values}


TOPICS = {
    'slave_pose': (PoseStamped, lambda msg: _xyz(msg.pose.position)),
    'wrench': (WrenchStamped, lambda msg: _xyz(msg.wrench.force)),
    'master_energy': (Vector3Stamped, lambda msg: _xyz(msg.vector)),
    'slave_energy': (Vector3Stamped, lambda msg: _xyz(msg.vector)),
    'diagnostics': (DiagnosticArray, lambda msg: [_diagnostics(msg)]),
}


def _recorder(topic, kept, values):
    def record(msg):
        if not kept:
            print(f'first {topic}', flush=True)
        kept.append([time.monotonic(), *values(msg)])
    return record


def main(topics):
    """Record until a signal, then print the records; return 0."""
    rclpy.init()
    node = rclpy.create_node('remote_recorder')
    records = {topic: [] for topic in topics}
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
    for topic in topics:
        msg_type, values = TOPICS[topic]
        node.create_subscription(msg_type, topic, _recorder(topic, records[topic], values), qos)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop = []  # not an Event: Event.set() in a signal handler can deadlock
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda signum, _frame: stop.append(signum))
    print('ready', flush=True)
    while not stop:
        executor.spin_once(timeout_sec=0.05)
    print(json.dumps(records), flush=True)
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
