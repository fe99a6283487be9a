#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The MuJoCo Panda behind the bridge: tracking, contact transparency, and what it costs.

Four parts, figures only (no asserts):

- step: PandaArm.step() in this process (controller and one 1 ms MuJoCo step), in free space
  and pressing on the table, and mujoco.mj_step alone; p50 and p99 in us.
- chain: the venv's kraft_master_arm_sim and kraft_master_teleop on a domain of their own
  (scale 1, max_linear_speed 1 m/s, tool_mass and tool_com of the simulated hand), with a
  stand-in master in this process publishing `pose` every 2 ms; the bridge's input timeouts
  1 s, max_tracking_error 0.2 m, max_force 40 N (see the constants). Free-space strokes: a sine of
  5 cm amplitude along y, slow (0.25 Hz, 79 mm/s peak) and fast (1 Hz, 314 mm/s peak), three
  periods each; the tracking error is the distance from each measured_cp to the master's
  position mapped 1:1 from the registration (the whole chain's lag) and to the bridge's last
  servo_cp (the arm's own lag), p50 and p99 in mm. Contact: the master holds the hand 10, 20
  and 30 mm below the table top for 4 s each; the table's force on the hand at the moment of
  the arm's last diagnostics (from the physics' contacts) against the force the master gets
  (the mean of its wrenches stamped in the 50 ms after), and the hand's peak-to-peak over the
  half second before. Jumps: the largest step between consecutive servo_cp and measured_cp in
  the 0.5 s after enable (the master far from the arm) and after a clutch release (the master
  moved 20 mm while clutched).
- port: PandaArm in this process, at the bridge's slave port. The commanded hand height
  swings PORT_SWING m about PORT_DEPTH m below the table top at 2, 5 and 10 Hz, for each
  translational stiffness; over PORT_CYCLES cycles, the energy the arm side hands back per
  cycle (mJ), the table's force on the hand (from the physics' contacts) times the commanded
  motion (what the slave port books: it pairs the force with servo_cp's motion), times the
  hand's own motion (what the table really exchanged), and the impedance's spring force
  (stiffness times how far the hand is from servo_cp) times the commanded motion (the energy
  servo_cp's motion puts into the arm, its spring included). Positive: energy out of the arm
  side.
- cost: each process's CPU over the chain part (from /proc), and the arm's real-time factor
  and step CPU from its diagnostics (one value a second: min, median).
"""
import argparse
import collections
import math
import os
import pathlib
import subprocess
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, WrenchStamped
from kraft_master_driver.simulation.arms.panda import Gains, HOME, PandaArm, Table
import mujoco
import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Bool, String
from std_srvs.srv import SetBool

BIN = pathlib.Path(sys.executable).parent
AMPLITUDE = 0.05  # m
STROKES = (('slow', 0.25), ('fast', 1.0))  # Hz
DEPTHS = (0.01, 0.02, 0.03)  # m below the table top
CLUTCH_TRAVEL = 0.02  # m the master moves while clutched
PERIOD = 0.002  # s between master poses
# The bridge's input timeouts (s): its default 0.1 s faulted on this 2-core machine loaded about
# 6 times over its cores, where the arm's physics thread stalled longer (arm_timeout).
TIMEOUT_S = 1.0
# m: the bridge's default 0.05 faulted in the strokes there (the arm lagged its command by
# 50 mm when its physics ran at a real-time factor of 0.3); wider, to measure the lag.
MAX_TRACKING_ERROR = 0.2
MAX_FORCE = 40.0  # N: the bridge's default 10 N would clip the deeper presses
PORT_DEPTH, PORT_SWING, PORT_CYCLES = 0.01, 0.005, 3  # m, m, cycles measured
PORT_FREQUENCIES = (2.0, 5.0, 10.0)  # Hz
PORT_STIFFNESSES = (1000.0, 2500.0, 5000.0)  # N/m: the arm node's default up to its largest


def percentiles(values, scale=1.0):
    """Return 'p50 X p99 Y' of `values` times `scale`."""
    values = np.asarray(values) * scale
    return f'p50 {np.percentile(values, 50):.2f} p99 {np.percentile(values, 99):.2f}'


def step_costs(count=5000):
    """Time PandaArm.step in free space and in contact, and mj_step alone; print them."""
    arm = PandaArm()

    def timed(action):
        times = []
        for _ in range(count):
            began = time.perf_counter()
            action()
            times.append(time.perf_counter() - began)
        return percentiles(times, 1e6)
    spare = mujoco.MjData(arm.model)  # the arm without its controller falls: reset each step

    def bare_step():
        spare.qpos[:7], spare.qvel[:] = HOME, 0.0
        mujoco.mj_step(arm.model, spare)
    print(f'mujoco.mj_step alone:          {timed(bare_step)} us (with a reset of the state)')
    print(f'PandaArm.step, free space:     {timed(arm.step)} us')
    start, quaternion = arm.tool_position(), arm.tool_quaternion()
    pressed = start - (0.0, 0.0, start[2] - Table().height + 0.02)
    for _ in range(2000):
        arm.command_pose(pressed, quaternion, arm.time)
        arm.step()
    assert arm.table_contact_force()[2] > 1.0, 'the hand is not on the table'
    print(f'PandaArm.step, on the table:   {timed(arm.step)} us')


def port_energy(stiffness, frequency):
    """
    Return the energy (J per cycle) out of the arm side, three ways.

    By the port's books, at the hand, and by the impedance's spring against the commanded
    motion.
    """
    arm = PandaArm(gains=Gains(translational_stiffness=stiffness))
    start, quaternion = arm.tool_position(), arm.tool_quaternion()
    middle = Table().height - PORT_DEPTH
    target = start.copy()
    while arm.time < 1.0:  # down onto the table, then settle
        target[2] = start[2] + (middle - start[2]) * min(1.0, arm.time / 0.5)
        arm.command_pose(target, quaternion, arm.time)
        arm.step()
    began = arm.time
    booked = exchanged = spring = 0.0
    commanded, hand = target[2], arm.tool_position()[2]
    while (elapsed := arm.time - began) < (PORT_CYCLES + 1) / frequency:
        target[2] = middle + PORT_SWING * math.sin(2.0 * math.pi * frequency * elapsed)
        arm.command_pose(target, quaternion, arm.time)
        arm.step()
        force, now_at = arm.table_contact_force()[2], arm.tool_position()[2]
        if elapsed >= 1.0 / frequency:  # the first cycle is the swing's start
            booked += force * (target[2] - commanded)
            exchanged += force * (now_at - hand)
            spring += stiffness * (now_at - target[2]) * (target[2] - commanded)
        commanded, hand = target[2], now_at
    return booked / PORT_CYCLES, exchanged / PORT_CYCLES, spring / PORT_CYCLES


def print_port_energies():
    """Print port_energy() for each stiffness and frequency."""
    print(f'the arm at the slave port: commanded hand {1e3 * PORT_DEPTH:g} mm into the table, '
          f'swinging +-{1e3 * PORT_SWING:g} mm; energy out of the arm side per cycle (mJ), '
          "by the port's books (force x servo_cp motion) / at the hand (force x hand motion) / "
          "the impedance's spring (stiffness x (hand - servo_cp) x servo_cp motion)")
    for stiffness in PORT_STIFFNESSES:
        cells = []
        for frequency in PORT_FREQUENCIES:
            booked, exchanged, spring = port_energy(stiffness, frequency)
            cells.append(f'{frequency:g} Hz {1e3 * booked:+8.2f} / {1e3 * exchanged:+7.2f}'
                         f' / {1e3 * spring:+7.2f}')
        print(f'  {stiffness:6.0f} N/m: ' + ' | '.join(cells))


def cpu_seconds(pid):
    """Return the user and system CPU seconds of process `pid` so far."""
    fields = pathlib.Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


class Master:
    """The stand-in master and the recorders, on one DDS domain."""

    def __init__(self, domain_id):
        """Join the domain: publish pose, record the arm, the bridge and the diagnostics."""
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node('arm_sim_benchmark', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.records = {topic: collections.deque(maxlen=100000)
                        for topic in ('measured_cp', 'servo_cp', 'wrench', '/diagnostics')}
        for msg_type, topic in ((PoseStamped, 'measured_cp'), (PoseStamped, 'servo_cp'),
                                (WrenchStamped, 'wrench'), (DiagnosticArray, '/diagnostics')):
            self.node.create_subscription(
                msg_type, topic, lambda m, q=self.records[topic]: q.append((stamp(m), m)),
                reliable)
        self.states = []
        self.node.create_subscription(
            String, 'operating_state', lambda m: self.states.append(m.data),
            QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.pose_pub = self.node.create_publisher(PoseStamped, 'pose', reliable)
        self.clutch_pub = self.node.create_publisher(Bool, 'clutch', reliable)
        self.enable_client = self.node.create_client(SetBool, 'enable')
        self.master = np.array([0.12, -0.05, 0.2])
        self.sent = collections.deque(maxlen=100000)  # (time, master position)
        # The recorders' callbacks run in a thread of their own, so that none waits for the
        # publishing pace (four topics come at up to 1 kHz).
        self._spinner = threading.Thread(target=self._spin, daemon=True)
        self._spinner.start()

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:  # noqa: B902 - the context ends under it at close()
            pass

    def publish(self):
        """Publish the master's pose once and note it."""
        msg = PoseStamped()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.header.frame_id = 'kraft_master_base'
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (
            float(v) for v in self.master)
        msg.pose.orientation.w = 1.0
        self.pose_pub.publish(msg)
        self.sent.append((stamp(msg), self.master.copy()))

    def run(self, seconds, motion=None):
        """Publish every PERIOD for `seconds`; motion(t) gives the master's position."""
        began = time.time()
        while (now := time.time()) - began < seconds:
            if motion is not None:
                self.master = motion(now - began)
            self.publish()
            time.sleep(max(PERIOD - (time.time() - now), 0.0))

    def run_until(self, condition, timeout=120.0):
        """Publish until `condition()` holds."""
        deadline = time.time() + timeout
        while not condition():
            if time.time() > deadline:
                raise RuntimeError(f'not met in {timeout} s: {condition}')
            self.run(0.01)

    def enable(self):
        """Call enable until the bridge accepts; return its answer."""
        self.enable_client.wait_for_service(timeout_sec=120.0)
        while True:
            future = self.enable_client.call_async(SetBool.Request(data=True))
            self.run_until(future.done)
            if future.result().success or 'no fresh' not in future.result().message:
                return future.result()
            self.run(0.1)

    def close(self):
        """Leave the domain."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def stamp(msg):
    """Return the time in a message's header (s, system clock: every process here shares it)."""
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def position(msg):
    """Return a PoseStamped's position."""
    p = msg.pose.position
    return np.array((p.x, p.y, p.z))


def diagnostics_of(master, name):
    """Return the (time, values) of each diagnostics status whose name ends with `name`."""
    found = []
    for received, msg in list(master.records['/diagnostics']):
        for status in msg.status:
            if status.name.endswith(name):
                found.append((received, {kv.key: kv.value for kv in status.values}))
    return found


def largest_step(master, topic, began, ended):
    """Return (largest distance in m between consecutive poses, count) of `topic` in a span."""
    points = np.array([position(m) for t, m in list(master.records[topic])
                       if began <= t <= ended])
    if len(points) < 2:
        return math.nan, len(points)
    return float(np.max(np.linalg.norm(np.diff(points, axis=0), axis=1))), len(points)


def print_jump(master, label, began, seconds=0.5):
    """Print the largest steps of servo_cp and measured_cp in the `seconds` after `began`."""
    ended = began + seconds
    (command, commands), (hand, hands) = (largest_step(master, topic, began, ended)
                                          for topic in ('servo_cp', 'measured_cp'))
    print(f'{label}: largest step of servo_cp {1e3 * command:.3f} mm ({commands} poses), of '
          f'the measured hand {1e3 * hand:.3f} mm ({hands} poses) in the {seconds:.1f} s after')


def stroke_errors(master, began, ended, registration):
    """Return the errors (m) of measured_cp to the mapped master and to the last servo_cp."""
    master_arm0, master0 = registration
    sent_times = np.array([t for t, _ in master.sent])
    sent = np.array([p for _, p in master.sent])
    commands = [(t, position(m)) for t, m in list(master.records['servo_cp'])
                if began <= t <= ended]
    command_times = np.array([t for t, _ in commands])
    to_master, to_command = [], []
    for received, msg in list(master.records['measured_cp']):
        if not began + 0.5 <= received <= ended:
            continue
        index = np.searchsorted(sent_times, received) - 1
        mapped = master_arm0 + sent[index] - master0
        to_master.append(np.linalg.norm(position(msg) - mapped))
        index = np.searchsorted(command_times, received) - 1
        if index >= 0:
            to_command.append(np.linalg.norm(position(msg) - commands[index][1]))
    command_to_master = []
    for received, command in commands:
        if began + 0.5 <= received:
            index = np.searchsorted(sent_times, received) - 1
            command_to_master.append(np.linalg.norm(
                command - (master_arm0 + sent[index] - master0)))
    return to_master, to_command, command_to_master


def chain(seconds_per_depth=4.0):
    """Run the chain part and print its figures."""
    domain_id = 200 + os.getpid() % 30
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    mass, com = PandaArm().tool_mass_properties()
    master = Master(domain_id)
    arm = subprocess.Popen([str(BIN / 'kraft_master_arm_sim')], env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    bridge = subprocess.Popen(
        [str(BIN / 'kraft_master_teleop'), '--ros-args', '-p', 'max_linear_speed:=1.0',
         '-p', f'max_tracking_error:={MAX_TRACKING_ERROR}', '-p', f'max_force:={MAX_FORCE}',
         *(item for name in ('master_timeout', 'arm_timeout', 'ft_timeout')
           for item in ('-p', f'{name}:={TIMEOUT_S}')),
         '-p', f'tool_mass:={mass!r}', '-p',
         'tool_com:=[' + ', '.join(repr(float(v)) for v in com) + ']'],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    try:
        master.run_until(lambda: master.records['measured_cp']
                         and master.pose_pub.get_subscription_count())
        master.run(1.0)
        cpu_start = {name: cpu_seconds(p.pid) for name, p in (('arm', arm), ('bridge', bridge))}
        cpu_start['master (this process)'] = time.process_time()
        wall_start = time.time()
        answer = master.enable()
        print(f'enable: {answer.message}')
        enabled = time.time()
        master.run(0.5)
        print_jump(master, 'at enable',
                   wall_start, enabled - wall_start + 0.5)
        arm0 = position(master.records['measured_cp'][-1][1])
        registration = (arm0, master.master.copy())
        centre = master.master.copy()
        for label, frequency in STROKES:
            began = time.time()
            master.run(3.0 / frequency + 0.5, lambda t, f=frequency: centre + (
                0.0, AMPLITUDE * math.sin(2.0 * math.pi * f * t), 0.0))
            to_master, to_command, command_to_master = stroke_errors(
                master, began, time.time(), registration)
            print(f'{label} stroke ({frequency:g} Hz, peak '
                  f'{2e3 * math.pi * frequency * AMPLITUDE:.0f} mm/s): arm to mapped master '
                  f'{percentiles(to_master, 1e3)} mm; arm to its servo_cp '
                  f'{percentiles(to_command, 1e3)} mm; servo_cp to mapped master '
                  f'{percentiles(command_to_master, 1e3)} mm ({len(to_master)} poses)')
            master.master = centre
            master.run(1.0)
        top = Table().height
        for depth in DEPTHS:
            master.master = centre + (0.0, 0.0, top - arm0[2] - depth)
            master.run(seconds_per_depth)
            # The arm's diagnostics carry the table's force at one moment a second: the force
            # felt is the mean of the master's wrenches stamped in the 50 ms after it.
            snapshot, values = diagnostics_of(master, 'simulated arm')[-1]
            arm_force = np.array([float(v) for v in values['table contact force (N)'].split(',')])
            near = [(m.wrench.force.x, m.wrench.force.y, m.wrench.force.z)
                    for t, m in list(master.records['wrench'])
                    if snapshot - 0.01 <= t <= snapshot + 0.05]
            if not near:
                print(f'{1e3 * depth:.0f} mm below the top: no wrench within 50 ms of the '
                      f"arm's diagnostics (bridge: {master.states[-1]})")
                continue
            felt = np.mean(near, axis=0)
            heights = [position(m)[2] for t, m in list(master.records['measured_cp'])
                       if snapshot - 0.5 <= t <= snapshot]
            print(f'{1e3 * depth:.0f} mm below the top: felt {np.round(felt, 2).tolist()} N, '
                  f'table on the hand {np.round(arm_force, 2).tolist()} N, felt/table z '
                  f'{felt[2] / arm_force[2]:.3f}; hand p-p {1e3 * np.ptp(heights):.3f} mm')
        master.master = centre
        master.run(1.0)
        # Clutched, the master moves CLUTCH_TRAVEL along y; released, the arm must not follow
        # that travel in one jump.
        master.clutch_pub.publish(Bool(data=True))
        master.run(0.5, lambda t: centre + (0.0, CLUTCH_TRAVEL * min(t / 0.3, 1.0), 0.0))
        released = time.time()
        master.clutch_pub.publish(Bool(data=False))
        master.run(0.5)
        print_jump(master, f'at clutch release (the master moved {1e3 * CLUTCH_TRAVEL:.0f} mm '
                   'while clutched)', released)
        wall = time.time() - wall_start
        cpu = {'arm': cpu_seconds(arm.pid) - cpu_start['arm'],
               'bridge': cpu_seconds(bridge.pid) - cpu_start['bridge'],
               'master (this process)': time.process_time() - cpu_start['master (this process)']}
        print('bridge states: ' + ' -> '.join(master.states))
        print(f'CPU over {wall:.1f} s: ' + ', '.join(
            f'{name} {100.0 * seconds / wall:.0f} %' for name, seconds in cpu.items()))
        arm_diagnostics = [v for t, v in diagnostics_of(master, 'simulated arm')
                           if t >= wall_start]
        factors = [float(v['real-time factor']) for v in arm_diagnostics]
        steps = [float(v['step CPU (us)']) for v in arm_diagnostics]
        print(f'arm real-time factor over {len(factors)} s: min {min(factors):.3f}, median '
              f'{np.median(factors):.3f}; step CPU median {np.median(steps):.0f} us; dropped '
              f'after stalls {arm_diagnostics[-1]["dropped after stalls (s)"]} s in all')
    finally:
        master.close()
        for process in (bridge, arm):
            process.terminate()
            process.wait(timeout=60)


def main(argv=None):
    """Run the parts asked for (all by default) and print their figures."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('parts', nargs='*', choices=('step', 'chain', 'port', []), default=[])
    args = parser.parse_args(argv)
    parts = args.parts or ['step', 'chain', 'port']
    print(f'$ {" ".join(sys.argv)}')
    print('load before: ' + subprocess.run(['uptime'], capture_output=True,
                                           text=True).stdout.strip())
    if 'step' in parts:
        step_costs()
    if 'chain' in parts:
        chain()
    if 'port' in parts:
        print_port_energies()
    print('load after: ' + subprocess.run(['uptime'], capture_output=True,
                                          text=True).stdout.strip())
    return 0


if __name__ == '__main__':
    sys.exit(main())
