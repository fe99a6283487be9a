#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
What the loop saves per message by handling CDR bytes itself, and what garbage collection costs.

Side by side in one run, each call paced once per millisecond as in the loop (cold caches):
- taking a WrenchStamped: rclpy's typed take against a raw take plus cdr.decode_wrench_stamped;
- publishing a JointState to a subscriber in another process: a filled rclpy message against
  the bytes of cdr.JointStateEncoder;
- one full garbage collection with the driver's modules loaded, before and after gc.freeze().
Prints median and p90 in microseconds, and the CPU share the hypervisor stole meanwhile.
"""
import argparse
import gc
import os
import subprocess
import sys
import time

from benchmarks.machine import cpu_times, steal_fraction
from kraft_master_driver.nodes import cdr
# Loaded for the garbage collection figure.
import kraft_master_driver.nodes.driver  # noqa: F401
import numpy as np

JOINT_NAMES = [f'kraft_joint{i}' for i in range(1, 7)]
FRAME = 'kraft_master_base'


def run_subscriber():
    """Subscribe to joint_states until interrupted (the receiving end of the publish figures)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from sensor_msgs.msg import JointState
    rclpy.init()
    node = rclpy.create_node('messages_benchmark_subscriber')
    node.create_subscription(JointState, 'joint_states', lambda msg: None, 10)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass


def paced(function, count):
    """Call function() count times, once per millisecond; return the durations (us)."""
    durations = []
    for _ in range(count):
        time.sleep(0.001)
        start = time.perf_counter_ns()
        function()
        durations.append((time.perf_counter_ns() - start) / 1e3)
    return np.array(durations)


def take_figures(node, count):
    import rclpy
    from geometry_msgs.msg import WrenchStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    publisher = node.create_publisher(WrenchStamped, 'wrench', qos)
    subscription = node.create_subscription(WrenchStamped, 'wrench', lambda msg: None, qos)
    while publisher.get_subscription_count() == 0:
        rclpy.spin_once(node, timeout_sec=0.01)
    msg = WrenchStamped()
    msg.header.frame_id = FRAME
    msg.wrench.torque.z = 0.5

    def take(raw):
        def one():
            with subscription.handle:
                taken = subscription.handle.take_message(WrenchStamped, raw)
            if raw:
                cdr.decode_wrench_stamped(taken[0])
        return one

    figures = {}
    for name, raw in (('typed take', False), ('raw take + decode', True)):
        durations = []
        for _ in range(count):
            publisher.publish(msg)
            time.sleep(0.001)
            start = time.perf_counter_ns()
            take(raw)()
            durations.append((time.perf_counter_ns() - start) / 1e3)
        figures[name] = np.array(durations)
    return figures


def publish_figures(node, count):
    import rclpy
    from sensor_msgs.msg import JointState
    publisher = node.create_publisher(JointState, 'joint_states', 10)
    subscriber = subprocess.Popen(
        [sys.executable, '-m', 'benchmarks.messages', '--role', 'subscriber'])
    try:
        while publisher.get_subscription_count() == 0:
            rclpy.spin_once(node, timeout_sec=0.01)
        msg = JointState(name=JOINT_NAMES)
        msg.header.frame_id = FRAME
        encoder = cdr.JointStateEncoder(FRAME, JOINT_NAMES, (6, 6, 6))
        values = [0.1 * i for i in range(6)]

        def typed():
            msg.header.stamp.sec, msg.header.stamp.nanosec = 1, 2
            msg.position, msg.velocity, msg.effort = values, values, values
            publisher.publish(msg)

        def packed():
            publisher.publish(encoder.encode(1, 2, values, values, values))

        return {'typed publish': paced(typed, count), 'packed CDR publish': paced(packed, count)}
    finally:
        subscriber.terminate()
        subscriber.wait()


def collection_figures(count):
    def full():
        gc.collect()
    before = paced(full, count)
    gc.freeze()
    after = paced(full, count)
    gc.unfreeze()
    return {'gc.collect()': before, 'gc.collect() after freeze': after}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--count', type=int, default=3000, help='calls per figure (3000)')
    parser.add_argument('--role', choices=('subscriber',), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == 'subscriber':
        return run_subscriber()

    import rclpy
    rclpy.init()
    node = rclpy.create_node('messages_benchmark')
    machine_start = cpu_times()
    figures = {**take_figures(node, args.count), **publish_figures(node, args.count),
               **collection_figures(max(args.count // 30, 10))}
    steal = steal_fraction(machine_start, cpu_times())
    node.destroy_node()
    rclpy.shutdown()
    print(f'paced once per ms, Python {sys.version.split()[0]}, {os.cpu_count()} CPUs, '
          f'CPU stolen by the hypervisor during the run: {steal:.0%}')
    print(f'{"":28}{"median us":>10}{"p90 us":>10}')
    for name, durations in figures.items():
        print(f'{name:28}{np.median(durations):10.1f}{np.percentile(durations, 90):10.1f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
