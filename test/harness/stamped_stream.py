# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
A stream of stamped poses and its one-way delays, for benchmarks/zenoh_link.py.

Run inside a host of netns.TwoHosts (both hosts share the machine's clock):

    python stamped_stream.py receive             # 'ready', 'first', on SIGINT one JSON line
    python stamped_stream.py publish --rate 1000 --seconds 10

`publish` waits for a subscriber of `pose`, then publishes PoseStamped CDR bytes stamped with
the system clock at each tick of its grid (late ticks are skipped, never sent in a burst) and
exits. `receive` takes `pose` raw, best effort, and records the system clock at each message
minus its stamp, printing 'first' at the first; on SIGINT it prints {"delays_ns": [...]}.
"""
import argparse
import json
import signal
import sys
import time

from geometry_msgs.msg import PoseStamped
from kraft_master_driver.nodes import cdr
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.qos import QoSProfile, ReliabilityPolicy

POSE = cdr.StampedDoublesDecoder('PoseStamped', 7)
VALUES = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)


def publish(node, rate_hz, seconds):
    """Publish poses at `rate_hz` for `seconds` once a subscriber is matched."""
    publisher = node.create_publisher(PoseStamped, 'pose', QoSProfile(
        depth=10, reliability=ReliabilityPolicy.RELIABLE))
    while publisher.get_subscription_count() == 0:
        time.sleep(0.01)
    encoder = cdr.StampedDoublesEncoder('kraft_master_base', 7)
    period = 1.0 / rate_hz
    start = next_tick = time.monotonic()
    while next_tick - start < seconds:
        sec, nanosec = divmod(time.time_ns(), 1_000_000_000)
        publisher.publish(encoder.encode(sec, nanosec, VALUES))
        next_tick += period
        now = time.monotonic()
        if next_tick > now:
            time.sleep(next_tick - now)
        else:
            next_tick += period * int((now - next_tick) / period)


def receive(node):
    """Record delays until SIGINT, then print them."""
    delays = []

    def on_pose(data):
        received = time.time_ns()
        sec, nanosec, _, _ = POSE.decode(data)
        # Kept before 'first' is said: the test's SIGINT follows it at once.
        delays.append(received - (sec * 1_000_000_000 + nanosec))
        if len(delays) == 1:
            print('first', flush=True)

    node.create_subscription(PoseStamped, 'pose', on_pose, QoSProfile(
        depth=100, reliability=ReliabilityPolicy.BEST_EFFORT), raw=True)
    print('ready', flush=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException, RuntimeError):
        # RuntimeError: the signal shut the context down while the spin built a wait set (as
        # in remote_recorder.py); a full CI run lost the delays so, with a traceback.
        pass
    print(json.dumps({'delays_ns': delays}), flush=True)


def main():
    """Publish or receive; return 0."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('mode', choices=('publish', 'receive'))
    parser.add_argument('--rate', type=float, default=1000.0)
    parser.add_argument('--seconds', type=float, default=10.0)
    args = parser.parse_args()
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    rclpy.init()
    node = rclpy.create_node(f'stamped_stream_{args.mode}')
    if args.mode == 'publish':
        publish(node, args.rate, args.seconds)
    else:
        receive(node)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
