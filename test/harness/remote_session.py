# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Teleoperation across a delaying, lossy link, one push into the stiff wall (tests, benchmark).

Two hosts (netns.TwoHosts: two network namespaces joined by a veth pair): on the master host
the installed driver at 1 kHz on one DDS domain, driving the simulated hand controller that runs
in this process ('hold' operator) over TCP inside the master host (not a pty: with a busy loop
per core, the pty's kernel worker thread held the driver's poll() for up to 5 s in about a
third of the sessions), and kraft_master_link_emulator relaying to the arm's domain with half
the round trip each way and the given loss (with neither delay nor loss, no emulator: all
share a domain); on the arm's host the installed bridge (kraft_master_teleop, enabled at start,
so with the master at home) and the simulated arm behind it: the point mass
(kraft_master_slave_sim) and its wall WALL_BELOW m down, or the MuJoCo Panda
(kraft_master_arm_sim) and its table. A recorder on each host (remote_recorder.py). The
operator's hand pulls the master PAST m through the arm's surface (the arm follows one to one)
over RAMP s, holds HOLD s, goes back over RAMP s and rests SETTLE s. run_row() returns the
figures: master peak-to-peak along the wall normal over the last WINDOW s of the hold, the
slave's largest penetration, the energy the channel generated (from both ports' observers), the
steady force at the slave and the force the operator feels (J^T F read back from the torques
the device received), the master-slave drift after the release, the one-way delays and losses
each side measured.
"""
import collections
import json
import math
import pathlib
import signal
import subprocess
import sys
import threading
import time
from typing import NamedTuple

from harness.driver import executable, installed_env, next_domain_id
from harness.netns import TwoHosts
from kraft_master_driver.core import kinematics
from kraft_master_driver.link.protocol import DEFAULT_TORQUE_SCALE
from kraft_master_driver.nodes.driver_parameters import PARAMETERS as DRIVER_PARAMETERS
from kraft_master_driver.simulation.master.model import joints_to_actuators, Workspace
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
import numpy as np

RECORDER = pathlib.Path(__file__).resolve().parent / 'remote_recorder.py'
ARM = 'right'
HOME_THETA = Workspace().home()
HOME = kinematics.forward(HOME_THETA, ARM)[:3, 3]
NORMAL = np.array([0.0, 0.0, 1.0])
WALL_BELOW = 0.03  # m from the master's home down to the wall
PAST = 0.025  # m the operator's hand aims past the wall
RAMP, HOLD, WINDOW, SETTLE = 1.0, 5.0, 2.0, 2.0  # s
# The benchmark's arm: 1 kg pushing with up to 100 N (see the README).
SLAVE = {'mass': 1.0, 'max_acceleration': 100.0}
# The bridge: one to one, the tool's orientation kept (a point mass has none to follow), forces
# up to its largest limit reflected (the earlier slave reflected them unlimited), timeouts that
# a loaded machine's stalls do not trip (a stale pose registers the master anew), and the slave
# port's energy at the arm's 500 Hz, as the earlier slave sent it; a tracking limit the wall
# does not trip (it holds the arm short of its command, PAST m and more with passivity off).
BRIDGE = {'orientation': 'fixed', 'max_force': 200.0, 'master_timeout': 2.0,
          'arm_timeout': 2.0, 'ft_timeout': 2.0, 'rate_hz': 500.0, 'enable_at_start': 'true',
          'max_tracking_error': 1.0}
# Pose and master_energy at 200 Hz. At 500 Hz the relay, bridge, arm and recorders (all Python)
# kept both cores busy on an idle machine: the pose reached the bridge 93 ms late at median
# where the emulator adds 50, 30 % of it missing, the arm's contact force 0.35 to 2 N; at
# 200 Hz, 53 ms, 5.5 % and 3.3 N (test_remote_teleop.py, two runs each).
PUBLISH_DECIMATION = 5
# The driver admits wrenches this much older than the emulated one-way delay.
MAX_WRENCH_AGE_S = DRIVER_PARAMETERS['max_wrench_age'].default


def actuator_target(depth):
    """Return the actuator coordinates with the wrist `depth` m below home (shoulder, elbow)."""
    theta = HOME_THETA.copy()
    goal = HOME - depth * NORMAL
    for _ in range(20):
        pose, jacobian = kinematics.forward_and_jacobian(theta, ARM)
        theta[:3] += np.linalg.lstsq(jacobian[:3, :3], goal - pose[:3, 3], rcond=None)[0]
    return joints_to_actuators(theta)


def vector(values):
    """Format floats for `-p name:=[...]`."""
    return '[' + ', '.join(f'{float(v)!r}' for v in values) + ']'


def diagnostics_values(records, since):
    """Return {key: [float values]} of the diagnostics received after `since`."""
    values = collections.defaultdict(list)
    for t, items in records:
        if t >= since:
            for key, value in items.items():
                try:
                    values[key].append(float(value))
                except ValueError:
                    pass
    return values


def start(host, prefix, domain_id, name, parameters):
    """Start installed executable `name` in `host` with `-p` parameters."""
    command = [executable(prefix, name), '--ros-args']
    for parameter, value in parameters:
        command += ['-p', f'{parameter}:={value}']
    return host.popen(command, env=host.ros_env(domain_id, installed_env(prefix, domain_id)),
                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


class Recorder:
    """remote_recorder.py running in a host; records() stops it and returns what it got."""

    def __init__(self, host, prefix, domain_id, topics, env=None):
        """Start recording `topics` in `host`; by default on domain_id across the veth."""
        self.topics = topics
        self.process = host.popen(
            [sys.executable, RECORDER, *topics],
            env=env or host.ros_env(domain_id, installed_env(prefix, domain_id)),
            stdout=subprocess.PIPE, text=True)
        assert self.process.stdout.readline().strip() == 'ready'
        self.first = set()
        threading.Thread(target=self._read_firsts, daemon=True).start()

    def _read_firsts(self):
        for line in self.process.stdout:
            if not line.startswith('first '):
                self.output = line
                return
            self.first.add(line.split()[1])

    def records(self):
        """Stop the recorder; return {topic: [[receipt time, values...], ...]}."""
        self.process.send_signal(signal.SIGINT)
        try:
            self.process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            printed = 'its records' if hasattr(self, 'output') else 'nothing'
            raise AssertionError(f'the recorder of {", ".join(self.topics)} did not end within '
                                 f'60 s of SIGINT, having printed {printed}') from None
        deadline = time.monotonic() + 10.0
        while not hasattr(self, 'output') and time.monotonic() < deadline:
            time.sleep(0.01)
        return json.loads(self.output)


class Arm(NamedTuple):
    """The simulated arm behind the bridge: where it starts and where its surface is."""

    executable: str
    parameters: tuple  # (name, value) of the arm node
    bridge: tuple  # (name, value) the bridge needs for this arm
    start: np.ndarray  # m, its tool's position at start (arm base frame)
    surface: np.ndarray  # m, a point of the surface it meets (arm base frame)
    surface_below: float  # m from its start down to the surface
    driver: tuple = ()  # (name, value) the driver needs for this arm


def point_mass_arm():
    """Return the point-mass arm (kraft_master_slave_sim) starting at the master's home."""
    surface = HOME - WALL_BELOW * NORMAL
    return Arm('kraft_master_slave_sim', (
        ('start_position', vector(HOME)), ('box.stiffness', 0.0),
        ('wall.point', vector(surface)), ('wall.normal', vector(NORMAL)),
        *((name, float(value)) for name, value in SLAVE.items())), (), HOME, surface,
        WALL_BELOW)


def panda_arm():
    """Return the MuJoCo Panda (kraft_master_arm_sim, its defaults) and its table."""
    # MuJoCo and the demo's settings only where the Panda is asked for.
    from kraft_master_driver.simulation.arms.panda import PandaArm
    from kraft_master_driver.tools.demo import (
        BRIDGE as DEMO_BRIDGE, MUJOCO_BRIDGE, MUJOCO_DRIVER, TABLE_Z)
    start = PandaArm().tool_position()
    # The bridge as the demo sets it for the Panda: its tool, the box in front of it.
    bridge = tuple((name, value) for name, value in MUJOCO_BRIDGE.items()
                   if name not in DEMO_BRIDGE)
    return Arm('kraft_master_arm_sim', (), bridge, start,
               np.array([start[0], start[1], TABLE_Z]), float(start[2] - TABLE_Z),
               tuple(MUJOCO_DRIVER.items()))


ARMS = {'point-mass': point_mass_arm, 'mujoco': panda_arm}


def run_row(prefix, round_trip_ms, loss, passivity, seed, arm='point-mass', past=PAST,
            arm_parameters=(), bridge_parameters=(), driver_parameters=()):
    """
    Run one session on two hosts; return its figures (NamespacesRefused if not allowed).

    `past`: m the operator's hand aims past the arm's surface; `arm_parameters`: (name, value)
    given to the arm's node besides its own; `bridge_parameters`, `driver_parameters`: likewise,
    the bridge's and the driver's (after the arm's own settings for them).
    """
    arm = ARMS[arm]()
    simulator = SimulatedKraftMaster(arm=ARM, operator='hold', record=20000, transport='tcp')
    samples = []
    sampling = threading.Event()

    def sample():
        scale = np.array(DEFAULT_TORQUE_SCALE, dtype=float)
        while not sampling.wait(0.002):
            theta = simulator.joint_angles()
            counts = np.array(simulator.received[-1][1].counts if simulator.received else [0] * 5)
            samples.append((time.monotonic(), theta, counts / scale))

    sampler = threading.Thread(target=sample, daemon=True)
    master_domain = next_domain_id()
    # No delay and no loss to emulate: driver and bridge talk directly across the veth, on one
    # domain, so that the latencies are the network's and DDS's, not the relay's.
    direct = round_trip_ms == 0 and loss == 0
    slave_domain = master_domain if direct else next_domain_id()
    wall_point = HOME - arm.surface_below * NORMAL  # the arm's surface, seen from the master
    on = 'true' if passivity else 'false'
    one_way = round_trip_ms / 2e3
    try:
        with TwoHosts() as (master_host, slave_host):
            with master_host.entered():
                port = simulator.start()
            start(master_host, prefix, master_domain, 'kraft_master_node', [
                ('port', port), ('arm', ARM), ('force_enabled_at_start', 'true'),
                ('loop_rate_hz', 1000.0), ('publish_decimation', PUBLISH_DECIMATION),
                ('passivity', on), ('max_wrench_age', MAX_WRENCH_AGE_S + one_way), *arm.driver,
                *driver_parameters])
            if not direct:
                start(master_host, prefix, master_domain, 'kraft_master_link_emulator', [
                    ('slave_domain_id', slave_domain), ('seed', seed),
                    ('to_slave.topics', "['pose', 'master_energy']"),
                    ('to_master.topics', "['wrench', 'slave_energy', 'contact_model']"),
                    ('to_slave.delay', one_way), ('to_master.delay', one_way),
                    ('to_slave.loss', loss), ('to_master.loss', loss)])
            start(slave_host, prefix, slave_domain, 'kraft_master_teleop', [
                ('passivity', on), *BRIDGE.items(), *arm.bridge, *bridge_parameters])
            # The arm starts where the master's wrist rests: the bridge registers the two there.
            start(slave_host, prefix, slave_domain, arm.executable,
                  [*arm.parameters, *arm_parameters])
            master = Recorder(master_host, prefix, master_domain,
                              ('master_energy', 'diagnostics'))
            far = Recorder(slave_host, prefix, slave_domain,
                           ('measured_cp', 'servo_cp', 'wrench', 'slave_energy', 'diagnostics'))
            deadline = time.monotonic() + 90.0
            # The bridge's first servo_cp: it is enabled.
            while not ({'measured_cp', 'servo_cp', 'slave_energy'} <= far.first
                       and 'master_energy' in master.first):
                assert time.monotonic() < deadline, ('driver, emulator, bridge or arm did not '
                                                     'start, or the bridge was not enabled')
                time.sleep(0.05)
            sampler.start()
            marks = operate(simulator, arm.surface_below + past)
            sampling.set()
            sampler.join()
            return figures(samples, master.records(), far.records(), marks, wall_point, arm)
    finally:
        sampling.set()
        simulator.stop()


def operate(simulator, depth):
    """Push the master `depth` m down, hold, release, rest; return the phases' starts."""
    home, pushed = joints_to_actuators(HOME_THETA), actuator_target(depth)
    marks = {}
    for phase, start_at, end, seconds in (('push', home, pushed, RAMP),
                                          ('hold', pushed, pushed, HOLD),
                                          ('release', pushed, home, RAMP),
                                          ('settle', home, home, SETTLE)):
        marks[phase] = time.monotonic()
        glide(simulator, start_at, end, seconds)
    marks['end'] = time.monotonic()
    return marks


def glide(simulator, start_at, end, seconds):
    """Move the operator's hand from actuators `start_at` to `end` over `seconds`, smoothly."""
    t0 = time.monotonic()
    while (elapsed := time.monotonic() - t0) < seconds:
        blend = 0.5 - 0.5 * math.cos(math.pi * elapsed / seconds)
        simulator.hold_at(start_at + blend * (end - start_at))
        time.sleep(0.01)


def figures(samples, master, far, marks, wall_point, arm):
    """Return the row's figures from what was recorded."""
    times = np.array([s[0] for s in samples])
    thetas = np.array([s[1] for s in samples])
    positions = kinematics.forward(thetas, ARM)[:, :3, 3]
    depths = (wall_point - positions) @ NORMAL
    window = (times >= marks['release'] - WINDOW) & (times < marks['release'])
    felt = []
    for theta, (_, _, torques) in zip(thetas[window], np.array(samples, dtype=object)[window]):
        joint = np.array([torques[0], torques[1] + torques[2], *torques[2:]])
        jacobian = kinematics.jacobian(theta, ARM)
        felt.append(np.linalg.lstsq(jacobian[:3, :5].T, joint, rcond=None)[0] @ NORMAL)
    slave_at = np.array([r[1:] for r in far['measured_cp']])
    slave_depth = float(np.max((arm.surface - slave_at) @ NORMAL))
    slave_force = [np.array(r[1:]) @ NORMAL for r in far['wrench']
                   if marks['release'] - WINDOW <= r[0] < marks['release']]
    energies = (master['master_energy'][-1][1:], far['slave_energy'][-1][1:])
    generated = sum(e[1] for e in energies) - sum(e[0] for e in energies)
    drift = np.linalg.norm((slave_at[-1] - arm.start) - (positions[-1] - HOME))
    ours = diagnostics_values(master['diagnostics'], marks['hold'])
    theirs = diagnostics_values(far['diagnostics'], marks['hold'])
    force_at_slave = float(np.mean(slave_force)) if slave_force else math.nan
    force_felt = float(np.mean(felt)) if felt else math.nan
    return {
        'master_pp_mm': 1e3 * float(np.ptp(depths[window])),
        'master_depth_mm': 1e3 * float(np.mean(depths[window])),
        'slave_penetration_mm': 1e3 * slave_depth,
        'energy_generated_j': float(generated),
        'dissipated_master_j': float(energies[0][2]),
        'dissipated_slave_j': float(energies[1][2]),
        'force_slave_n': force_at_slave,
        'force_felt_n': force_felt,
        'felt_ratio': force_felt / force_at_slave if force_at_slave else math.nan,
        'drift_mm': 1e3 * float(drift),
        'pose_to_slave_median_ms': _median(theirs['master to slave delay median (ms)']),
        'pose_to_slave_p99_ms': _largest(theirs['master to slave delay p99 (ms)']),
        'wrench_to_driver_median_ms': _median(ours['slave to master delay median (ms)']),
        'wrench_to_driver_p99_ms': _largest(ours['slave to master delay p99 (ms)']),
        'loss_to_slave_pct': _median(theirs['master to slave loss (%)']),
        'loss_to_master_pct': _median(ours['slave to master loss (%)']),
    }


def _median(values):
    return float(np.median(values)) if values else math.nan


def _largest(values):
    return float(np.max(values)) if values else math.nan
