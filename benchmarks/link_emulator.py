#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
What the link emulator adds to a 1 kHz stream, and how close it keeps to a set delay.

A source process publishes PoseStamped at 1 kHz, stamped when published; this process receives
them and takes receipt minus stamp as the one-way latency. Side by side in one run:
- direct: source and receiver in one domain, no emulator;
- emulator, delay 0: source in the master's domain, receiver in the slave's, the emulator
  (kraft_master_link_emulator, started as `python -m`) between them;
- emulator, delay 50 ms: the same with to_slave.delay 0.05.
Prints count, p50, p99 and max latency (ms) per row, the emulator's own record of what it
added (received to published), and the load average; writes the figures as JSON.
"""
import argparse
import json
import os
import pathlib
import re
import subprocess
import sys
import time

import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[1]
RATE_HZ = 1000.0


def run_source(seconds):
    """Publish stamped poses at 1 kHz for `seconds` (sleeping to deadlines), then exit."""
    from geometry_msgs.msg import PoseStamped
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    rclpy.init()
    node = rclpy.create_node('emulator_benchmark_source')
    publisher = node.create_publisher(
        PoseStamped, 'pose', QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    while not publisher.get_subscription_count():
        time.sleep(0.01)
    time.sleep(1.0)  # let the far end match too (the emulator's own publisher, if any)
    msg = PoseStamped()
    clock = node.get_clock()
    start = time.monotonic()
    for i in range(int(seconds * RATE_HZ)):
        msg.header.stamp = clock.now().to_msg()
        publisher.publish(msg)
        time.sleep(max(0.0, start + (i + 1) / RATE_HZ - time.monotonic()))


def receive(domain_id, source, emulator):
    """Record the latency (s) of each pose arriving in `domain_id` until `source` exits."""
    from geometry_msgs.msg import PoseStamped
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node('emulator_benchmark_receiver', context=context)
    clock = node.get_clock()
    latencies = []

    def on_pose(msg):
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        latencies.append((clock.now().nanoseconds - stamp) * 1e-9)

    node.create_subscription(PoseStamped, 'pose', on_pose,
                             QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    while source.poll() is None:
        if emulator is not None and emulator.poll() is not None:
            source.kill()
            raise RuntimeError('the emulator stopped:\n' + emulator.communicate()[0])
        executor.spin_once(timeout_sec=0.05)
    for _ in range(20):  # what is still on its way (the delayed run keeps 50 ms in flight)
        executor.spin_once(timeout_sec=0.01)
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    return np.array(latencies)


def python_process(args, domain_id):
    """Start `python args` on `domain_id` with this machine's discovery settings."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONPATH=str(REPO),
               ROS_AUTOMATIC_DISCOVERY_RANGE=os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE',
                                                            'LOCALHOST'))
    return subprocess.Popen([sys.executable, *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def run_row(name, seconds, base_domain, delay=None):
    """Measure one row; with `delay` (s) the emulator sits between two domains."""
    master, slave = base_domain, base_domain + 1
    emulator = None
    if delay is not None:
        emulator = python_process(
            ['-m', 'kraft_master_driver.nodes.link_emulator', '--ros-args',
             '-p', f'slave_domain_id:={slave}', '-p', f'to_slave.delay:={delay}',
             '-p', "to_slave.topics:=['pose:pose:geometry_msgs/msg/PoseStamped']"], master)
    source = python_process(['-m', 'benchmarks.link_emulator', '--source', str(seconds)], master)
    latencies = receive(slave if emulator else master, source, emulator)
    row = {'row': name, 'sent': int(seconds * RATE_HZ), 'received': len(latencies)}
    for key, q in (('p50', 50), ('p99', 99), ('max', 100)):
        row[f'{key}_ms'] = round(float(np.percentile(latencies, q)) * 1e3, 3)
    row['min_ms'] = round(float(latencies.min()) * 1e3, 3)
    if emulator:
        emulator.send_signal(2)
        output = emulator.communicate(timeout=30)[0]
        own = re.findall(r'to_slave: (.*)', output)[-1]
        row['emulator_own'] = own
    return row


def main():
    """Run the three rows and print the table."""
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--seconds', type=float, default=10.0, help='stream length per row')
    parser.add_argument('--domain', type=int, default=60, help='first of the domains used')
    parser.add_argument('--json', default='link_emulator.json', help='output file')
    parser.add_argument('--source', type=float, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.source:
        return run_source(args.source)
    rows = [run_row('direct', args.seconds, args.domain),
            run_row('emulator, delay 0', args.seconds, args.domain + 2, delay=0.0),
            run_row('emulator, delay 50 ms', args.seconds, args.domain + 4, delay=0.05)]
    print(f'{"row":24} {"sent":>6} {"recv":>6} {"min":>8} {"p50":>8} {"p99":>8} {"max":>8}'
          ' (ms, receipt - stamp)')
    for row in rows:
        print(f'{row["row"]:24} {row["sent"]:6d} {row["received"]:6d} {row["min_ms"]:8.3f} '
              f'{row["p50_ms"]:8.3f} {row["p99_ms"]:8.3f} {row["max_ms"]:8.3f}')
    for row in rows[1:]:
        print(f'{row["row"]}: emulator\'s own record: {row["emulator_own"]}')
    load = os.getloadavg()
    print(f'load average {load[0]:.1f} on {os.cpu_count()} cores')
    pathlib.Path(args.json).write_text(json.dumps({'rows': rows, 'load': load}, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
