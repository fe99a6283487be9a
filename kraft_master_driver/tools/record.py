# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_record: record the driver's topics into a rosbag2 directory, without ros2 bag.

Takes the options of `ros2 bag record` that apply (-o, -s, topic names, -a) and by default
records the driver's topics of each --namespace (the root one if none is given), with the
absolute /diagnostics. Topics are subscribed to as their publishers appear, raw and with the
reliability and durability the publishers offer, and written with BagRecorder as
rosbag2 Jazzy writes them: receive time as the log time, the publisher's source timestamp as
the publish time, the offered QoS profiles and the publishers' type hash. A line every
--status-period seconds says what is recorded and how much; Ctrl-C or SIGTERM closes a
complete bag and exits 0.
"""
import argparse
from datetime import datetime
import importlib
from pathlib import Path
import signal
import sqlite3
import sys
import time

from kraft_master_driver.bag.common import DRIVER_TOPICS, SessionError, typestore
from kraft_master_driver.bag.recorder import BagRecorder, qos_profile, STORAGES
from kraft_master_driver.core.process import STOP_SIGNALS, stop_with_parent
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

DISCOVERY_PERIOD_S = 0.1  # how often the graph is searched for new topics (as rosbag2)
SUBSCRIPTION_DEPTH = 1000  # one second of a 1 kHz topic queued while the recorder is busy


def driver_topics(namespaces):
    """Return the driver's topics in `namespaces` and the absolute /diagnostics, sorted."""
    topics = {'/diagnostics'}
    for namespace in namespaces:
        prefix = '/' + namespace.strip('/') if namespace.strip('/') else ''
        topics.update(f'{prefix}/{name}' for name in DRIVER_TOPICS)
    return sorted(topics)


def message_class(msgtype):
    """Return the rclpy message class of a type name such as sensor_msgs/msg/JointState."""
    package, interface, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.{interface}'), name)


def offered_qos(info):
    """Return the QoS profile a publisher offers, as rosbag2 stores it."""
    qos = info.qos_profile
    return qos_profile(
        reliability=qos.reliability.name, durability=qos.durability.name,
        history=qos.history.name, depth=qos.depth, deadline_ns=qos.deadline.nanoseconds,
        lifespan_ns=qos.lifespan.nanoseconds, liveliness=qos.liveliness.name,
        liveliness_lease_duration_ns=qos.liveliness_lease_duration.nanoseconds,
        avoid_ros_namespace_conventions=qos.avoid_ros_namespace_conventions)


def type_hash(infos):
    """Return the publishers' RIHS01 type hash, '' if they disagree (rosbag2's rule)."""
    hashes = {str(info.topic_type_hash) for info in infos if info.topic_type_hash.version > 0}
    return hashes.pop() if len(hashes) == 1 else ''


def subscription_qos(infos):
    """Return a QoS that matches every publisher: reliable or transient-local only if all are."""
    def every(policy, value):
        return bool(infos) and all(getattr(info.qos_profile, policy) == value for info in infos)
    return QoSProfile(
        depth=SUBSCRIPTION_DEPTH,
        reliability=(ReliabilityPolicy.RELIABLE if every('reliability', ReliabilityPolicy.RELIABLE)
                     else ReliabilityPolicy.BEST_EFFORT),
        durability=(DurabilityPolicy.TRANSIENT_LOCAL
                    if every('durability', DurabilityPolicy.TRANSIENT_LOCAL)
                    else DurabilityPolicy.VOLATILE))


class Recorder:
    """A node that subscribes to topics as they appear and writes them into a BagRecorder."""

    def __init__(self, context, bag, topics=None):
        """Record `topics` (absolute names), or every topic when None, into `bag`."""
        self.bag = bag
        self.wanted = topics
        self.node = rclpy.create_node('kraft_master_record', context=context,
                                      start_parameter_services=False)
        self.subscriptions = {}

    def discover(self):
        """Subscribe to the wanted topics that have publishers; return the new topics."""
        found = []
        for topic, types in self.node.get_topic_names_and_types():
            if topic in self.subscriptions or (self.wanted is not None and
                                               topic not in self.wanted):
                continue
            infos = self.node.get_publishers_info_by_topic(topic)
            if not infos or len(types) != 1 or types[0] not in typestore().types:
                continue
            self.bag.add_topic(topic, types[0], [offered_qos(info) for info in infos],
                               type_hash(infos))
            self.subscriptions[topic] = self.node.create_subscription(
                message_class(types[0]), topic, self._writer(topic), subscription_qos(infos),
                raw=True)
            found.append(f'{topic} ({types[0]})')
        return found

    def _writer(self, topic):
        write = self.bag.write

        def record(data, info):
            received = info['received_timestamp'] or time.time_ns()
            write(topic, received, data, info['source_timestamp'] or received,
                  info['publication_sequence_number'] or 0)
        return record

    def close(self):
        """Destroy the node."""
        self.node.destroy_node()


def status_line(bag, elapsed_s):
    """Return one line: how long, how many messages, and how many per topic."""
    counts = ', '.join(f'{topic} {count}' for topic, count in bag.counts.items())
    return (f'{elapsed_s:.0f} s: {sum(bag.counts.values())} messages'
            + (f' ({counts})' if counts else ', no topic found yet'))


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line and exit 1."""

    def error(self, message):
        """Print `message` on one line and exit 1."""
        self.exit(1, f'{self.prog}: {message}\n')


def _parser():
    parser = _Parser(
        prog='kraft_master_record',
        description="Record the Kraft Master driver's topics into a rosbag2 bag (what "
                    '`ros2 bag record` writes, for machines without it). By default the '
                    "driver's topics (joint_states, pose, pots, wrench, rate_command, "
                    'diagnostics) of each --namespace, and /diagnostics. Ctrl-C or SIGTERM '
                    'closes the bag.')
    parser.add_argument('topics', nargs='*', metavar='TOPIC',
                        help='record these topics instead (absolute names, or relative to /)')
    parser.add_argument('-a', '--all', action='store_true',
                        help='record every topic that has a publisher')
    parser.add_argument('--namespace', nargs='+', default=['/'], metavar='NS',
                        help="the driver's namespaces, e.g. right left (default: /)")
    parser.add_argument('-o', '--output', metavar='DIR',
                        help='the bag directory to create (default: rosbag2_YYYY_MM_DD-HH_MM_SS)')
    parser.add_argument('-s', '--storage', choices=STORAGES, default='mcap',
                        help='storage format (default: mcap)')
    parser.add_argument('--status-period', type=float, default=2.0, metavar='S',
                        help='seconds between status lines, 0 for none (default: 2)')
    return parser


def main(argv=None):
    """Record until Ctrl-C, SIGTERM or SIGHUP; return 0, or 1 if the bag cannot be written."""
    parser = _parser()
    args = parser.parse_args(rclpy.utilities.remove_ros_args(
        sys.argv[1:] if argv is None else argv))
    if args.all and args.topics:
        parser.error('give topic names or -a, not both')
    if args.status_period < 0:
        parser.error('--status-period must be 0 or more')
    output = Path(args.output or datetime.now().strftime('rosbag2_%Y_%m_%d-%H_%M_%S'))
    topics = (None if args.all else
              sorted({'/' + t.lstrip('/') for t in args.topics}) or driver_topics(args.namespace))
    stop = []
    for signum in STOP_SIGNALS:
        signal.signal(signum, lambda signum, _frame: stop.append(signum))
    stop_with_parent()
    try:
        bag = BagRecorder(output, args.storage)
    except SessionError as error:
        print(f'kraft_master_record: {error}', file=sys.stderr)
        return 1
    context = rclpy.Context()
    rclpy.init(args=argv, context=context, signal_handler_options=SignalHandlerOptions.NO)
    recorder = Recorder(context, bag, topics)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(recorder.node)
    print(f'Recording into {output} ({args.storage}): '
          + ('every topic' if topics is None else ' '.join(topics)), flush=True)
    started = next_discovery = next_status = time.monotonic()
    status = 0
    try:
        while not stop:
            now = time.monotonic()
            if now >= next_discovery:
                for found in recorder.discover():
                    print(f'Subscribed to {found}', flush=True)
                next_discovery = now + DISCOVERY_PERIOD_S
            if args.status_period and now >= next_status + args.status_period:
                next_status = now
                print(status_line(bag, now - started), flush=True)
            executor.spin_once(timeout_sec=DISCOVERY_PERIOD_S)
    except (OSError, sqlite3.Error) as error:
        print(f'kraft_master_record: cannot write to {output}: {error}', file=sys.stderr)
        status = 1
    finally:
        try:
            bag.close()
        except SessionError as error:
            print(f'kraft_master_record: {error}', file=sys.stderr)
            status = 1
        executor.shutdown()
        recorder.close()
        rclpy.try_shutdown(context=context)
    print(f'Closed {output}: {status_line(bag, time.monotonic() - started)}', flush=True)
    return status


if __name__ == '__main__':
    sys.exit(main())
