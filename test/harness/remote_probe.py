# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
A stand-in for the slave's machine, run as a process on the far host by the two-host tests.

It waits for the driver's `pose` (printing `pose <count> <min one-way delay s>` once it has
`--poses` of them), then publishes `--wrench` on `wrench` every 5 ms until the driver's
`joint_states` carry a torque, and prints `effort <six torques>`. Exit 0 on success, 1 (with
`timeout: ...`) when either does not happen within `--timeout` s.
"""
import argparse
import sys
import time

from geometry_msgs.msg import PoseStamped, WrenchStamped
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState


def main():
    """Run the probe; return the exit code."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--wrench', type=float, nargs=6, required=True)
    parser.add_argument('--frame', default='kraft_master_base')
    parser.add_argument('--poses', type=int, default=50)
    parser.add_argument('--timeout', type=float, default=60.0)
    args = parser.parse_args()
    rclpy.init()
    node = rclpy.create_node('remote_probe')
    clock = node.get_clock()
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    delays, efforts = [], []

    def on_pose(msg):
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        delays.append(clock.now().nanoseconds * 1e-9 - stamp)

    node.create_subscription(PoseStamped, 'pose', on_pose, reliable)
    node.create_subscription(JointState, 'joint_states',
                             lambda msg: efforts.append(list(msg.effort)), reliable)
    wrench_pub = node.create_publisher(WrenchStamped, 'wrench', reliable)
    deadline = time.monotonic() + args.timeout
    while len(delays) < args.poses:
        if time.monotonic() > deadline:
            print(f'timeout: {len(delays)} poses arrived', flush=True)
            return 1
        rclpy.spin_once(node, timeout_sec=0.05)
    print(f'pose {len(delays)} {min(delays):.6f}', flush=True)
    msg = WrenchStamped()
    msg.header.frame_id = args.frame
    f, m = msg.wrench.force, msg.wrench.torque
    f.x, f.y, f.z, m.x, m.y, m.z = args.wrench
    while not (efforts and any(efforts[-1])):
        if time.monotonic() > deadline:
            print('timeout: no torque in joint_states', flush=True)
            return 1
        msg.header.stamp = clock.now().to_msg()
        wrench_pub.publish(msg)
        rclpy.spin_once(node, timeout_sec=0.005)
    print('effort ' + ' '.join(f'{value:.6f}' for value in efforts[-1]), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
