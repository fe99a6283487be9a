# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
An observer on the arm's host, run as a process there by the two-host tests.

Beside the bridge and the simulated arm, it waits for `--poses` of the driver's `pose`, then
for the bridge's `wrench` to have pushed for 0.3 s (past its force_resume_time ramp) and for
the driver's `joint_states` to carry a torque. It prints
`pose <count> <min one-way delay s>`, `wrench <force x y z of the last one>` and
`effort <six torques>`. Exit 0 on success, 1 (with `timeout: ...`) when any of them does not
come within `--timeout` s. It publishes nothing. run_probe() runs it in a host and returns
what it printed; assert_the_box_pushes_the_master() checks that.
"""
import argparse
import pathlib
import sys
import time

from geometry_msgs.msg import PoseStamped, WrenchStamped
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

PROBE = pathlib.Path(__file__).resolve()


def run_probe(host, env):
    """Run this probe in `host` with `env` to its end; return {'pose', 'wrench', 'effort'}."""
    result = host.run([sys.executable, PROBE, '--timeout', '90'], env=env,
                      capture_output=True, text=True, timeout=150)
    assert result.returncode == 0, result.stdout + result.stderr
    lines = dict(line.split(' ', 1) for line in result.stdout.splitlines() if ' ' in line)
    return {key: [float(v) for v in lines[key].split()]
            for key in ('pose', 'wrench', 'effort')}


def assert_the_box_pushes_the_master(seen):
    """Assert the bridge reflected the box's upward push and the driver turned it to torques."""
    force_x, force_y, force_z = seen['wrench']
    assert force_z > 1.0 and abs(force_x) + abs(force_y) < 0.1 * force_z, seen['wrench']
    assert any(abs(value) > 1e-3 for value in seen['effort'])


def main():
    """Run the observer; return the exit code."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--poses', type=int, default=50)
    parser.add_argument('--timeout', type=float, default=60.0)
    args = parser.parse_args()
    rclpy.init()
    node = rclpy.create_node('remote_probe')
    clock = node.get_clock()
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    delays, wrenches, efforts = [], [], []
    pushed_since = []  # when the wrenches became non-zero, while they stay so

    def on_pose(msg):
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        delays.append(clock.now().nanoseconds * 1e-9 - stamp)

    def on_wrench(msg):
        force = msg.wrench.force
        wrenches.append((force.x, force.y, force.z))
        if not any(wrenches[-1]):
            pushed_since.clear()
        elif not pushed_since:
            pushed_since.append(time.monotonic())

    node.create_subscription(PoseStamped, 'pose', on_pose, reliable)
    node.create_subscription(WrenchStamped, 'wrench', on_wrench, reliable)
    node.create_subscription(JointState, 'joint_states',
                             lambda msg: efforts.append(list(msg.effort)), reliable)
    deadline = time.monotonic() + args.timeout
    waits = (('poses', lambda: len(delays) >= args.poses),
             # Past the bridge's force_resume_time (0.1 s): the whole push, not its ramp.
             ('a wrench from the bridge', lambda: pushed_since and
              time.monotonic() - pushed_since[0] > 0.3),
             ('a torque in joint_states', lambda: efforts and any(efforts[-1])))
    for awaited, arrived in waits:
        while not arrived():
            if time.monotonic() > deadline:
                print(f'timeout: waiting for {awaited}; {len(delays)} poses arrived', flush=True)
                return 1
            rclpy.spin_once(node, timeout_sec=0.05)
    print(f'pose {len(delays)} {min(delays):.6f}', flush=True)
    print('wrench ' + ' '.join(f'{value:.6f}' for value in wrenches[-1]), flush=True)
    print('effort ' + ' '.join(f'{value:.6f}' for value in efforts[-1]), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
