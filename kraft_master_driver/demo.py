# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_demo: the paper's worked examples, then simulated teleoperation, live.

The driver runs against the simulated hand controller (its own process, on a real
pseudo-terminal), whose simulated operator pushes the wrist down and back; the simulated
slave arm follows the master's pose, meets a stiff wall 40 mm down, and its contact wrench
is reflected to the master as joint torques. A few refreshed lines show what happens.
"""
import argparse
import math
import os
import signal
import subprocess
import sys
import time

from kraft_master_driver import kinematics
from kraft_master_driver.calibration import ArmCalibration

SECTION_8_POTS = ((2086, 2683, 992, 1595, 1715, 2025), (2622, 1610, 2268, 1829, 2488, 1745))
SIMULATOR = [sys.executable, '-m', 'kraft_master_driver.simulator', '--operator', 'push']
DRIVER = [sys.executable, '-m', 'kraft_master_driver.node', '--ros-args',
          '-p', 'force_enabled_at_start:=true']
SLAVE = [sys.executable, '-m', 'kraft_master_driver.slave_sim']
EMULATOR = [sys.executable, '-m', 'kraft_master_driver.link_emulator', '--ros-args',
            '-p', 'to_slave.topics:=[pose, master_energy]',
            '-p', 'to_master.topics:=[wrench, slave_energy, slave_pose]']


def _rows(matrix, scales):
    return '\n'.join('    ' + ' '.join(f'{v * s:9.3f}' for v, s in zip(row, scales))
                     for row in matrix)


def print_examples(out=sys.stdout):
    """Print Section 8: pot counts -> joint angles -> 0T6 and 0J (mm in the printout)."""
    calibration = ArmCalibration.nominal('right')
    for number, pots in enumerate(SECTION_8_POTS, start=1):
        theta = calibration.pots_to_joints(pots)
        pose, jac = kinematics.forward_and_jacobian(theta)
        print(f'Section 8, example {number} (right arm): POT = {pots}', file=out)
        print('  th (deg) = ' + ', '.join(f'{math.degrees(t):.2f}' for t in theta), file=out)
        print('  0T6 (position in mm):', file=out)
        print(_rows(pose[:3], (1, 1, 1, 1000)), file=out)
        print('  0J (rows v in mm/rad, then w in rad/rad):', file=out)
        print(_rows(jac[:3], (1000,) * 6), file=out)
        print(_rows(jac[3:], (1,) * 6), file=out)
        print(file=out)


class Readout:
    """A client node that keeps the newest state of the teleoperation and formats it."""

    def __init__(self):
        """Subscribe to the driver's state, the slave's wrench and the diagnostics."""
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped, WrenchStamped
        import rclpy
        from sensor_msgs.msg import JointState

        rclpy.init()
        self.rclpy = rclpy
        self.node = rclpy.create_node('kraft_master_demo')
        self.latest = {}
        for msg_type, topic in ((JointState, 'joint_states'), (PoseStamped, 'pose'),
                                (WrenchStamped, 'wrench'), (PoseStamped, 'slave_pose'),
                                (DiagnosticArray, 'diagnostics')):
            self.node.create_subscription(
                msg_type, topic, lambda msg, topic=topic: self.latest.__setitem__(topic, msg), 10)

    def spin(self, seconds):
        """Process messages for about `seconds`."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.rclpy.spin_once(self.node, timeout_sec=max(0.0, deadline - time.monotonic()))

    def lines(self):
        """Return the readout: a few lines of text."""
        latest = self.latest
        if 'joint_states' not in latest:
            return ['waiting for the driver ...']
        state = latest['joint_states']
        diagnostics = {}
        for status in getattr(latest.get('diagnostics'), 'status', []):
            diagnostics.update({kv.key: kv.value for kv in status.values})
        p = latest['pose'].pose.position if 'pose' in latest else None
        wrench = latest['wrench'].wrench.force if 'wrench' in latest else None
        slave = latest['slave_pose'].pose.position if 'slave_pose' in latest else None
        link_errors = sum(int(diagnostics.get(f'link {k}', 0)) for k in (
            'timeouts', 'bad_crc', 'garbage_bytes', 'truncated', 'link_faults'))
        return [
            f'loop {diagnostics.get("loop rate (Hz)", "-"):>7} Hz | period p99 '
            f'{diagnostics.get("period p99 (ms)", "-")} ms | link errors {link_errors} | '
            f'force {diagnostics.get("force state", "-")}',
            'joints (deg)    ' + ' '.join(f'{math.degrees(v):8.2f}' for v in state.position),
            'torques (N*m)   ' + ' '.join(f'{v:8.3f}' for v in state.effort),
            'master wrist (mm) ' + (f'{1e3 * p.x:7.1f} {1e3 * p.y:7.1f} {1e3 * p.z:7.1f}'
                                    if p else '-'),
            'slave (mm)        ' + (f'{1e3 * slave.x:7.1f} {1e3 * slave.y:7.1f} '
                                    f'{1e3 * slave.z:7.1f}' if slave else '-')
            + '   (wall at z = -40.0)',
            'wrench on master (N) ' + (f'{wrench.x:7.2f} {wrench.y:7.2f} {wrench.z:7.2f}'
                                       if wrench else '-'),
        ]

    def close(self):
        """Leave ROS."""
        self.node.destroy_node()
        self.rclpy.try_shutdown()


def stop(processes):
    """Ctrl-C each process in turn (the driver first: it zeroes the device's torques)."""
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def teleoperate(duration, out=sys.stdout, delay_ms=0.0, passivity=False):
    """
    Run driver and slave for `duration` s (or until Ctrl-C), refreshing the readout.

    With delay_ms > 0 the slave runs on the next DDS domain and the link emulator relays
    between them with half of delay_ms each way; passivity turns it on at both ends.
    """
    simulator = subprocess.Popen(SIMULATOR, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                 text=True)
    port = simulator.stdout.readline().partition('port: ')[2].strip()
    passive = ['-p', f'passivity:={str(passivity).lower()}']
    slave_env, emulator = None, []
    if delay_ms > 0.0:
        slave_domain = (int(os.environ.get('ROS_DOMAIN_ID', '0')) + 1) % 233
        slave_env = dict(os.environ, ROS_DOMAIN_ID=str(slave_domain))
        one_way = delay_ms / 2e3
        emulator = [subprocess.Popen(
            [*EMULATOR, '-p', f'slave_domain_id:={slave_domain}',
             '-p', f'to_slave.delay:={one_way}', '-p', f'to_master.delay:={one_way}'],
            stdin=subprocess.DEVNULL)]
    processes = [subprocess.Popen([*DRIVER, '-p', f'port:={port}', *passive],
                                  stdin=subprocess.DEVNULL),
                 subprocess.Popen([*SLAVE, '--ros-args', *passive], stdin=subprocess.DEVNULL,
                                  env=slave_env), *emulator, simulator]
    readout = Readout()
    interactive = out.isatty()
    shown = 0
    try:
        end = time.monotonic() + duration
        while time.monotonic() < end:
            readout.spin(0.1 if interactive else 1.0)
            if any(process.poll() is not None for process in processes):
                print('a demo process ended early; see its messages above', file=out)
                return 1
            lines = readout.lines()
            if interactive and shown:
                out.write(f'\x1b[{shown}F\x1b[J')
            out.write('\n'.join(lines) + '\n')
            out.flush()
            shown = len(lines)
    except KeyboardInterrupt:
        pass
    finally:
        readout.close()
        stop(processes)
    return 0


def main(argv=None):
    """Print the examples and run the teleoperation demo."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--duration', type=float, default=20.0,
                        help='seconds of teleoperation (default 20); Ctrl-C ends it earlier')
    parser.add_argument('--delay-ms', type=float, default=0.0,
                        help='round trip between master and slave through the link emulator')
    parser.add_argument('--passivity', choices=('on', 'off'), default='off',
                        help='time-domain passivity at both ends (default off)')
    args = parser.parse_args(argv)
    print_examples()
    print(f'Simulated teleoperation for {args.duration:g} s (Ctrl-C to stop) ...', flush=True)
    return teleoperate(args.duration, delay_ms=args.delay_ms,
                       passivity=args.passivity == 'on')


if __name__ == '__main__':
    sys.exit(main())
