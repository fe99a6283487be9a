# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The fault suite's wrench source, run as a process of its own by harness.faults.WrenchSource.

It publishes WrenchStamped messages as the JSON lines on its stdin say.
"""
import json
import os
import select
import sys
import time

from geometry_msgs.msg import WrenchStamped
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy


def run_wrench_source():
    """
    Publish WrenchStamped on `wrench` as the JSON lines on stdin say, until stdin closes.

    Each line is {"rate_hz", "wrench", "frame_id", "stamp"}; prints 'ready' once the driver
    subscribes and 'switched <time_ns> <messages published before>' as each line takes effect.
    """
    rclpy.init(args=sys.argv)
    node = rclpy.create_node('fault_wrench_source')
    publisher = node.create_publisher(
        WrenchStamped, 'wrench', QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    while publisher.get_subscription_count() == 0:
        time.sleep(0.01)
    print('ready', flush=True)
    message = WrenchStamped()
    period_ns = offset_ns = published = 0
    zero_stamp = switched = False
    pending = b''
    due = time.monotonic_ns()
    while True:
        ahead = (due - time.monotonic_ns()) / 1e9 if period_ns else 0.1
        if select.select([0], [], [], ahead if ahead > 2e-4 else 0.0)[0]:
            chunk = os.read(0, 4096)
            if not chunk:
                break
            *lines, pending = (pending + chunk).split(b'\n')
            for line in lines:
                spec = json.loads(line)
                period_ns = int(1e9 / spec['rate_hz']) if spec['rate_hz'] else 0
                zero_stamp = spec['stamp'] == 'zero'
                offset_ns = 0 if zero_stamp else int(spec['stamp'] * 1e9)
                message.header.frame_id = spec['frame_id']
                w = message.wrench
                (w.force.x, w.force.y, w.force.z,
                 w.torque.x, w.torque.y, w.torque.z) = spec['wrench']
                switched, due = True, time.monotonic_ns()
            continue
        if not period_ns:
            if switched:
                print(f'switched {time.time_ns()} {published}', flush=True)
                switched = False
            continue
        now = time.monotonic_ns()
        if now < due:
            continue
        stamp_ns = 0 if zero_stamp else time.time_ns() + offset_ns
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        sent_ns = time.time_ns()
        publisher.publish(message)
        if switched:
            print(f'switched {sent_ns} {published}', flush=True)
            switched = False
        published += 1
        due += period_ns
        due = max(due, now - 100_000_000)  # fallen far behind: do not burst to catch up
    rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(run_wrench_source())
