#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The teleoperation bridge's latency, CPU and registration steps, every party in its own process.

The installed kraft_master_teleop runs beside a stand-in master (publishes `pose` at --rate,
1 kHz by default, takes `wrench`) and a stand-in arm (publishes `measured_cp` and `measured_cf`
at that rate, takes `servo_cp` and reports the newest one as its measured pose: an arm that
tracks perfectly). Both stand-ins publish CDR bytes and take their inputs raw in a paced loop,
as the driver does, so that they cost the machine little. The run:

1. the master holds still; the bridge is enabled (the step at enable: the first target against
   the arm's pose);
2. the master moves along x by 1 um per pose (1 mm/s at 1 kHz) for --duration s: each pose's
   position says which pose it was, each measured_cf's force which reading it was, so that
   every servo_cp and wrench is matched with the input that caused it;
3. the clutch is pressed for 1 s while the master goes on moving, then released (the step at
   release: a fresh registration must not jump by the master's travel meanwhile).

Printed: pose -> servo_cp and measured_cf -> wrench latency (p50, p99, max: from the stand-in's
clock just before publishing to when DDS handed the answer to the other stand-in, both on this
host's system clock), the bridge's CPU per input message, the largest target steps against one
pot count of the master at its home pose, and the CPU the hypervisor stole. Timings are printed,
never asserted.
"""
import argparse
import json
import math
import os
import pathlib
import platform
import shutil
import signal
import subprocess
import sys
import tempfile
import time

from benchmarks.machine import cpu_times, steal_fraction
from kraft_master_driver.core import kinematics, rotations
from kraft_master_driver.core.calibration import ArmCalibration
from kraft_master_driver.nodes import cdr
from kraft_master_driver.simulation.master.model import Workspace
import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[1]

STEP_M = 1e-6  # the master's travel per pose while moving: 1 mm/s at 1 kHz
MASTER_FRAME, ARM_FRAME, FT_FRAME = 'kraft_master_base', 'base_link', 'ft_sensor'
ARM_START = (0.5, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0)  # the arm's pose before enable: x, y, z, q
FORCE_CODES = 5000  # measured_cf's fx is 1 mN times (its number modulo this, plus 1)
# The bridge's input timeouts, longer than their defaults (0.1 s): on a shared machine a
# stand-in descheduled for 0.1 s would end the run in FAULT; what is measured here is latency.
TIMEOUTS = ('master_timeout:=1.0', 'arm_timeout:=1.0', 'ft_timeout:=1.0')
CLUTCH_S = 1.0
SETTLE_S = 0.5


def ros_env(domain_id):
    """Environment of every process of a run: local discovery, one private domain."""
    return dict(os.environ, ROS_DOMAIN_ID=str(domain_id),
                ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONPATH=str(REPO),
                PYTHONUNBUFFERED='1')


def master_home():
    """Return the master's wrist pose (x, y, z, qx, qy, qz, qw) at the simulator's home."""
    pose = kinematics.forward(Workspace().home())
    return (*pose[:3, 3], *rotations.rotation_to_quaternion(pose[:3, :3]))


def count_resolution(arm='right'):
    """Return the wrist's travel (m) and turn (rad) for one count of each pot at home."""
    calibration = ArmCalibration.nominal(arm)
    home = Workspace().home()
    pots = calibration.joints_to_pots(home)
    pose = kinematics.forward(home, arm)
    travel, turn = [], []
    for pot in range(6):
        moved = pots.copy()
        moved[pot] += 1.0
        other = kinematics.forward(calibration.pots_to_joints(moved), arm)
        travel.append(float(np.linalg.norm(other[:3, 3] - pose[:3, 3])))
        relative = pose[:3, :3].T @ other[:3, :3]
        turn.append(float(math.acos(max(-1.0, min(1.0, (np.trace(relative) - 1) / 2)))))
    return travel, turn


# -- the stand-ins -----------------------------------------------------------------------------

class PacedPeer:
    """A node whose one thread publishes and takes raw, once per period (no executor)."""

    def __init__(self, name, rate_hz):
        """Join the domain; SIGINT or SIGTERM ends run()."""
        import rclpy
        self.rate_hz = rate_hz
        rclpy.init()
        self.node = rclpy.create_node(name)
        self.stop = False
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._stop)

    def _stop(self, *_):
        self.stop = True

    def raw_subscription(self, msg_type, topic):
        from kraft_master_driver.nodes.ros_io import subscribe_raw
        return subscribe_raw(self.node, msg_type, topic, lambda _: None, 100)

    def publisher(self, msg_type, topic):
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        return self.node.create_publisher(
            msg_type, topic, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))

    def run(self, cycle):
        """Call cycle(i) once per period until stopped."""
        period_ns = int(1e9 / self.rate_hz)
        deadline, i = time.monotonic_ns(), 0
        while not self.stop:
            cycle(i)
            i += 1
            deadline += period_ns
            delay = deadline - time.monotonic_ns()
            if delay > 0:
                time.sleep(delay / 1e9)
            elif delay < -50 * period_ns:
                deadline = time.monotonic_ns()  # far behind: no burst to catch up

    def close(self):
        import rclpy
        self.node.destroy_node()
        rclpy.try_shutdown()


def run_master(out, capacity, rate_hz):
    """Publish pose at rate_hz (still until SIGUSR1, then moving); record the wrenches."""
    from geometry_msgs.msg import PoseStamped, WrenchStamped
    from kraft_master_driver.nodes.ros_io import take_all_received
    peer = PacedPeer('bridge_benchmark_master', rate_hz)
    pose_pub = peer.publisher(PoseStamped, 'pose')
    wrench_sub = peer.raw_subscription(WrenchStamped, 'wrench')
    while not peer.stop and not (pose_pub.get_subscription_count() and
                                 wrench_sub.get_publisher_count()):
        time.sleep(0.02)
    pathlib.Path(out + '.ready').touch()
    moving = []
    signal.signal(signal.SIGUSR1, lambda *_: moving.append(True))
    encoder = cdr.StampedDoublesEncoder(MASTER_FRAME, 7)
    home = master_home()
    sent = np.zeros(capacity, dtype=np.int64)  # publish time of the pose numbered by its index
    wrenches = np.zeros((capacity, 2), dtype=np.float64)  # receipt ns, fx
    counts = [0, 0]  # poses numbered, wrenches received

    def cycle(_):
        step = counts[0] if moving and counts[0] < capacity - 1 else None
        if step is not None:
            counts[0] += 1
            step = counts[0]
        now = time.time_ns()
        sec, nanosec = divmod(now, 1_000_000_000)
        x = home[0] + (STEP_M * step if step is not None else 0.0)
        pose_pub.publish(encoder.encode(sec, nanosec, (x, *home[1:])))
        if step is not None:
            sent[step] = now
        for data, received_ns in take_all_received(wrench_sub):
            if counts[1] < capacity:
                wrenches[counts[1]] = received_ns, cdr.decode_wrench_stamped(data)[3][0]
                counts[1] += 1
    peer.run(cycle)
    np.savez(out, sent=sent[:counts[0] + 1], wrenches=wrenches[:counts[1]])
    peer.close()


def run_arm(out, capacity, rate_hz):
    """Publish measured_cp (the newest servo_cp) and a numbered measured_cf at rate_hz."""
    from geometry_msgs.msg import PoseStamped, WrenchStamped
    from kraft_master_driver.nodes.ros_io import take_all_received
    peer = PacedPeer('bridge_benchmark_arm', rate_hz)
    pose_pub = peer.publisher(PoseStamped, 'measured_cp')
    ft_pub = peer.publisher(WrenchStamped, 'measured_cf')
    servo_sub = peer.raw_subscription(PoseStamped, 'servo_cp')
    while not peer.stop and not (pose_pub.get_subscription_count() and
                                 ft_pub.get_subscription_count() and
                                 servo_sub.get_publisher_count()):
        time.sleep(0.02)
    pathlib.Path(out + '.ready').touch()
    pose_encoder = cdr.StampedDoublesEncoder(ARM_FRAME, 7)
    ft_encoder = cdr.StampedDoublesEncoder(FT_FRAME, 6)
    decode_pose = cdr.StampedDoublesDecoder('PoseStamped', 7).decode
    sent = np.zeros(capacity, dtype=np.int64)  # publish time of the reading numbered by index
    targets = np.zeros((capacity, 8), dtype=np.float64)  # receipt ns, x, y, z, qx, qy, qz, qw
    received = [0]
    pose = [ARM_START]

    def cycle(i):
        for data, received_ns in take_all_received(servo_sub):
            values = decode_pose(data)[3]
            pose[0] = values
            if received[0] < capacity:
                targets[received[0]] = (received_ns, *values)
                received[0] += 1
        now = time.time_ns()
        sec, nanosec = divmod(now, 1_000_000_000)
        pose_pub.publish(pose_encoder.encode(sec, nanosec, pose[0]))
        now = time.time_ns()
        sec, nanosec = divmod(now, 1_000_000_000)
        ft_pub.publish(ft_encoder.encode(
            sec, nanosec, (1e-3 * (i % FORCE_CODES + 1), 0.0, 0.0, 0.0, 0.0, 0.0)))
        if i < capacity:
            sent[i] = now
    peer.run(cycle)
    np.savez(out, sent=sent[sent > 0], targets=targets[:received[0]])
    peer.close()


# -- the run -------------------------------------------------------------------------------------

def process_cpu_seconds(pid):
    """User + system CPU time of a process so far, from /proc."""
    fields = pathlib.Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def bridge_command(parameters, profile=None):
    """
    Return the command of the installed kraft_master_teleop, with -p NAME:=VALUE.

    With `profile`: the same module under cProfile, its statistics written there at the exit.
    """
    path = shutil.which('kraft_master_teleop', path=str(pathlib.Path(sys.executable).parent))
    if profile:
        command = [sys.executable, '-m', 'cProfile', '-o', profile,
                   '-m', 'kraft_master_driver.nodes.teleop']
    else:
        command = [path] if path else [sys.executable, '-m', 'kraft_master_driver.nodes.teleop']
    command.append('--ros-args')
    for parameter in (*TIMEOUTS, *parameters):
        command += ['-p', parameter]
    return command


class Coordinator:
    """A node in this process: calls enable, presses the clutch, watches operating_state."""

    def __init__(self, domain_id):
        """Join the domain."""
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Bool, String
        from std_srvs.srv import SetBool
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node('bridge_benchmark', context=self.context)
        self.states = []
        self.node.create_subscription(
            String, 'operating_state', lambda msg: self.states.append((time.time_ns(), msg.data)),
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.clutch = self.node.create_publisher(Bool, 'clutch', 10)
        self.enable_client = self.node.create_client(SetBool, 'enable')
        self._bool, self._set_bool = Bool, SetBool
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin(self, seconds):
        """Process callbacks for `seconds`."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)

    def enable(self, timeout=60.0):
        """Call enable until it succeeds (the inputs must be fresh first); return its time."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if not self.enable_client.wait_for_service(timeout_sec=1.0):
                continue
            future = self.enable_client.call_async(self._set_bool.Request(data=True))
            while not future.done() and time.monotonic() < deadline:
                self.executor.spin_once(timeout_sec=0.01)
            if future.done() and future.result().success:
                return time.time_ns()
            self.spin(0.2)
        raise RuntimeError(f'enable refused: {future.result().message if future.done() else ""}')

    def press_clutch(self, pressed):
        """Publish the clutch state (reliable, to the bridge); return the time."""
        while self.clutch.get_subscription_count() == 0:
            self.spin(0.05)
        now = time.time_ns()
        self.clutch.publish(self._bool(data=pressed))
        return now

    def close(self):
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def wait_ready(paths, processes, timeout=120.0):
    """Wait until each stand-in has matched the bridge (each touches a file)."""
    deadline = time.monotonic() + timeout
    while not all(os.path.exists(path) for path in paths):
        failed = [p.args for p in processes if p.poll() is not None]
        if failed or time.monotonic() > deadline:
            raise RuntimeError(f'stand-ins not matched with the bridge; exited: {failed}')
        time.sleep(0.05)


def stop(processes):
    """SIGINT the stand-ins, SIGTERM the bridge; SIGKILL only what does not end."""
    for process, sig in processes:
        if process.poll() is None:
            process.send_signal(sig)
    for process, _ in processes:
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def distribution(values_ns):
    """p50, p99, max (ms) and the count of latencies given in ns."""
    values = np.asarray(values_ns, dtype=float) / 1e6
    if values.size == 0:
        return {'p50': None, 'p99': None, 'max': None, 'n': 0}
    p50, p99 = np.percentile(values, (50, 99))
    return {'p50': p50, 'p99': p99, 'max': float(values.max()), 'n': int(values.size)}


def pose_latencies(targets, master_sent, until_ns):
    """Each servo_cp that followed a moving pose -> the time that pose was published (ns)."""
    latencies, seen = [], set()
    for row in targets[targets[:, 0] < until_ns]:
        step = round((row[1] - ARM_START[0]) / STEP_M)
        if 1 <= step < len(master_sent) and step not in seen and master_sent[step]:
            seen.add(step)
            latencies.append(row[0] - master_sent[step])
    return latencies


def force_latencies(wrenches, arm_sent, since_ns, until_ns):
    """Each wrench whose force names a reading -> the time that reading was published (ns)."""
    latencies = []
    numbers = np.arange(len(arm_sent))
    for received_ns, fx in wrenches[(wrenches[:, 0] > since_ns) & (wrenches[:, 0] < until_ns)]:
        code = round(fx * 1e3) - 1
        if not 0 <= code < FORCE_CODES:
            continue
        candidates = numbers[(numbers % FORCE_CODES == code) & (arm_sent <= received_ns)]
        if candidates.size:
            latencies.append(received_ns - arm_sent[candidates[-1]])
    return latencies


def largest_step(targets, start_ns, end_ns, before=None):
    """Largest change (m, rad) between consecutive targets received in [start, end)."""
    window = targets[(targets[:, 0] >= start_ns) & (targets[:, 0] < end_ns)][:, 1:]
    if before is not None:
        window = np.vstack([before, window])
    if len(window) < 2:
        return None, None
    travel = np.linalg.norm(np.diff(window[:, :3], axis=0), axis=1)
    dots = np.abs(np.sum(window[1:, 3:] * window[:-1, 3:], axis=1))
    turn = 2 * np.arccos(np.clip(dots, -1.0, 1.0))
    return float(travel.max()), float(turn.max())


def run(args, workdir):
    """Run the bridge and the stand-ins once; return the figures."""
    domain_id = args.domain_id or 100 + os.getpid() % 100
    env = ros_env(domain_id)
    capacity = int((args.duration + CLUTCH_S + 4 * SETTLE_S + 120) * args.rate)
    log = open(workdir / 'bridge.log', 'w')
    bridge = subprocess.Popen(bridge_command(args.set, args.profile), env=env, stdout=log,
                              stderr=subprocess.STDOUT)
    outs = {role: str(workdir / role) for role in ('master', 'arm')}
    peers = {role: subprocess.Popen([sys.executable, '-m', 'benchmarks.bridge', '--role', role,
                                     '--out', out, '--capacity', str(capacity),
                                     '--rate', str(args.rate)], env=env)
             for role, out in outs.items()}
    processes = [(peers['master'], signal.SIGINT), (peers['arm'], signal.SIGINT),
                 (bridge, signal.SIGTERM)]
    coordinator = None
    try:
        wait_ready([out + '.ready' for out in outs.values()], [p for p, _ in processes])
        coordinator = Coordinator(domain_id)
        enabled_ns = coordinator.enable()
        coordinator.spin(SETTLE_S)
        peers['master'].send_signal(signal.SIGUSR1)
        coordinator.spin(SETTLE_S)
        machine_start, cpu_start = cpu_times(), process_cpu_seconds(bridge.pid)
        window_start = time.time_ns()
        coordinator.spin(args.duration)
        window_end = time.time_ns()
        bridge_cpu = process_cpu_seconds(bridge.pid) - cpu_start
        steal = steal_fraction(machine_start, cpu_times())
        pressed_ns = coordinator.press_clutch(True)
        coordinator.spin(CLUTCH_S)
        released_ns = coordinator.press_clutch(False)
        coordinator.spin(SETTLE_S)
        states = list(coordinator.states)
    finally:
        if coordinator is not None:
            coordinator.close()
        stop(processes)
        log.close()
    master, arm = np.load(outs['master'] + '.npz'), np.load(outs['arm'] + '.npz')
    targets = arm['targets']
    window_s = (window_end - window_start) / 1e9
    # Inputs to the bridge in the window: a pose, a measured_cp and a measured_cf per period.
    inputs = 3 * args.rate * window_s
    travel, turn = count_resolution()
    before_enable = np.array([ARM_START])
    return {
        'duration_s': window_s,
        'pose_to_servo_cp_ms': distribution(
            pose_latencies(targets, master['sent'], pressed_ns)),
        'poses_sent': int(np.count_nonzero((master['sent'] > 0) & (master['sent'] < pressed_ns))),
        'measured_cf_to_wrench_ms': distribution(
            force_latencies(master['wrenches'], arm['sent'], enabled_ns, pressed_ns)),
        'readings_sent': int(np.count_nonzero((arm['sent'] > enabled_ns) &
                                              (arm['sent'] < pressed_ns))),
        'largest_gap_ms': {
            'master': float(np.diff(master['sent'][master['sent'] > 0]).max(initial=0) / 1e6),
            'arm': float(np.diff(arm['sent']).max(initial=0) / 1e6)},
        'bridge_cpu_per_input_us': 1e6 * bridge_cpu / inputs,
        'bridge_cores': bridge_cpu / window_s,
        'cpu_steal': steal,
        'step_at_enable': largest_step(targets, 0, enabled_ns + int(SETTLE_S * 1e9),
                                       before=before_enable),
        'step_at_clutch_press': largest_step(targets, pressed_ns - 100_000_000,
                                             pressed_ns + 500_000_000),
        'step_at_clutch_release': largest_step(targets, released_ns - 100_000_000,
                                               released_ns + int(SETTLE_S * 1e9)),
        'following_step_m': STEP_M * args.scale,
        'step_while_following': largest_step(targets, window_start, window_end),
        'master_travel_while_clutched_m': STEP_M * args.rate * (released_ns - pressed_ns) / 1e9,
        'rate_hz': args.rate,
        'count_travel_m': travel[:3],
        'count_turn_rad': turn[3:],
        'states': [state for _, state in states],
        'bridge_log': (workdir / 'bridge.log').read_text().splitlines()[-10:],
    }


def fmt(value, digits=3):
    return '-' if value is None else f'{value:.{digits}f}'


def print_figures(figures, scale):
    print(f'bridge latency, {figures["duration_s"]:.1f} s at {figures["rate_hz"]:g} Hz '
          f'({100 * figures["cpu_steal"]:.0f} % of the CPU stolen meanwhile):')
    print(f'{"path":>26} {"p50 ms":>7} {"p99 ms":>7} {"max ms":>7} {"answered":>17}')
    for name, key, sent in (('pose -> servo_cp', 'pose_to_servo_cp_ms', 'poses_sent'),
                            ('measured_cf -> wrench', 'measured_cf_to_wrench_ms',
                             'readings_sent')):
        d = figures[key]
        print(f'{name:>26} {fmt(d["p50"]):>7} {fmt(d["p99"]):>7} {fmt(d["max"]):>7} '
              f'{d["n"]:>7d} of {figures[sent]:>6d}')
    gaps = figures['largest_gap_ms']
    print(f'largest gap between two publishes of a stand-in: master {gaps["master"]:.1f} ms, '
          f'arm {gaps["arm"]:.1f} ms')
    print(f'bridge CPU: {figures["bridge_cpu_per_input_us"]:.0f} us per input message '
          f'(pose, measured_cp, measured_cf each at {figures["rate_hz"]:g} Hz), '
          f'{figures["bridge_cores"]:.2f} cores')
    one_count = min(figures['count_travel_m']) * scale
    one_turn = min(figures['count_turn_rad'])
    print(f'one pot count at the master\'s home pose: {1e3 * min(figures["count_travel_m"]):.3f}'
          f' to {1e3 * max(figures["count_travel_m"]):.3f} mm of wrist travel (pots 1-3), '
          f'{math.degrees(one_turn):.3f} to {math.degrees(max(figures["count_turn_rad"])):.3f}'
          f' deg of turn (pots 4-6); times scale {scale:g}: {1e3 * one_count:.3f} mm')
    print(f'largest step between consecutive targets of the arm (mm, deg); a pose moves the '
          f'target {1e3 * figures["following_step_m"]:.4f} mm, more where the bridge skipped '
          f'poses; the master moved {1e3 * figures["master_travel_while_clutched_m"]:.2f} mm '
          'while clutched:')
    for name, key in (('while following', 'step_while_following'),
                      ('at enable', 'step_at_enable'), ('at clutch press', 'step_at_clutch_press'),
                      ('at clutch release', 'step_at_clutch_release')):
        travel, turn = figures[key]
        verdict = '-' if travel is None else (
            'under one count' if travel < one_count and turn < one_turn else 'NOT under one count')
        print(f'{name:>26} {fmt(None if travel is None else 1e3 * travel, 4):>8} mm '
              f'{fmt(None if turn is None else math.degrees(turn), 4):>8} deg  {verdict}')
    print('operating states: ' + ' -> '.join(figures['states']))
    print("the bridge's last lines:\n  " + '\n  '.join(figures['bridge_log']))


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--duration', type=float, default=20.0,
                        help='measured seconds of following (default 20)')
    parser.add_argument('--rate', type=float, default=1000.0,
                        help="the stand-ins' publishing rate (Hz, default 1000)")
    parser.add_argument('--set', metavar='NAME:=VALUE', nargs='*', default=[],
                        help='extra bridge parameters, e.g. rate_hz:=200')
    parser.add_argument('--domain-id', type=int,
                        help='ROS_DOMAIN_ID of the run (default: 100 + pid modulo 100)')
    parser.add_argument('--json', help='write the figures here too')
    parser.add_argument('--profile', metavar='PATH',
                        help='run the bridge under cProfile and write its statistics to PATH, '
                        'then print the functions with the most time of their own')
    parser.add_argument('--role', choices=('master', 'arm'), help=argparse.SUPPRESS)
    parser.add_argument('--out', help=argparse.SUPPRESS)
    parser.add_argument('--capacity', type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == 'master':
        return run_master(args.out, args.capacity, args.rate)
    if args.role == 'arm':
        return run_arm(args.out, args.capacity, args.rate)
    args.scale = next((float(p.split(':=', 1)[1]) for p in args.set
                       if p.startswith('scale:=')), 1.0)
    with tempfile.TemporaryDirectory() as workdir:
        figures = run(args, pathlib.Path(workdir))
    print_figures(figures, args.scale)
    if args.profile:
        import pstats
        pstats.Stats(args.profile).sort_stats('tottime').print_stats(25)
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(
            {'machine': {'platform': platform.platform(), 'python': platform.python_version(),
                         'cpus': os.cpu_count()}, 'bridge_parameters': args.set,
             'figures': figures}, indent=2, default=float))
    return 0


if __name__ == '__main__':
    sys.exit(main())
