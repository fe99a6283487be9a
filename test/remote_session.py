# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Teleoperation across a delaying, lossy link, one push into the stiff wall (tests, benchmark).

The simulated hand controller runs in this process ('hold' operator), the installed driver at
1 kHz on one DDS domain, the installed slave simulator on another, and delay_relay.py between
them, holding every message for half the round trip and dropping the given fraction. The
operator's hand pulls the master PAST m through the slave's wall (the slave follows one to one)
over RAMP s, holds HOLD s, goes back over RAMP s and rests SETTLE s. run_row() returns the
figures: master peak-to-peak along the wall normal over the last WINDOW s of the hold, the
slave's largest penetration, the energy the channel generated (from both ports' observers), the
steady force at the slave and the force the operator feels (J^T F read back from the torques
the device received), the master-slave drift after the release, the one-way delays and losses
each side measured.
"""
import collections
import math
import pathlib
import subprocess
import sys
import threading
import time

from delay_relay import Side
from diagnostic_msgs.msg import DiagnosticArray
from driver_harness import DriverProcess, installed_env, next_domain_id
from geometry_msgs.msg import PoseStamped, Vector3Stamped, WrenchStamped
from kraft_master_driver import kinematics
from kraft_master_driver.protocol import DEFAULT_TORQUE_SCALE
from kraft_master_driver.simulator import joints_to_actuators, SimulatedKraftMaster, Workspace
import numpy as np
from rclpy.qos import QoSProfile, ReliabilityPolicy

RELAY = pathlib.Path(__file__).resolve().parent / 'delay_relay.py'

ARM = 'right'
HOME_THETA = Workspace().home()
HOME = kinematics.forward(HOME_THETA, ARM)[:3, 3]
NORMAL = np.array([0.0, 0.0, 1.0])
WALL_BELOW = 0.03  # m from the master's home down to the wall
PAST = 0.025  # m the operator's hand aims past the wall
RAMP, HOLD, WINDOW, SETTLE = 1.0, 5.0, 2.0, 2.0  # s
# The benchmark's slave: a 1 kg arm pushing with up to 100 N (see the README).
SLAVE = {'mass': 1.0, 'max_acceleration': 100.0}
# Pose and master_energy at 500 Hz: half the messages for the relay (one Python process).
PUBLISH_DECIMATION = 2


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


def xyz(v):
    """Return a Point or Vector3 as an array."""
    return np.array([v.x, v.y, v.z])


class Recorder:
    """Subscriptions on one domain, each keeping (receipt time, message)."""

    def __init__(self, domain_id, name, topics):
        """Listen to `topics` ((name, type), ...) on domain_id."""
        self.side = Side(domain_id, name)
        self.messages = {}
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
        for topic, msg_type in topics:
            kept = self.messages[topic] = collections.deque(maxlen=20000)
            self.side.node.create_subscription(
                msg_type, topic, lambda msg, kept=kept: kept.append((time.monotonic(), msg)),
                qos)
        self.side.thread.start()


def diagnostics_values(recorded, since):
    """Return {key: [float values]} of the diagnostics received after `since`."""
    values = collections.defaultdict(list)
    for t, array in recorded:
        if t >= since:
            for status in array.status:
                for item in status.values:
                    try:
                        values[item.key].append(float(item.value))
                    except ValueError:
                        pass
    return values


def run_row(prefix, round_trip_ms, loss, passivity, seed):
    """Run one row; return its figures."""
    simulator = SimulatedKraftMaster(arm=ARM, operator='hold', record=20000)
    port = simulator.start()
    master_domain, slave_domain = next_domain_id(), next_domain_id()
    wall_point = HOME - WALL_BELOW * NORMAL
    on = 'true' if passivity else 'false'
    driver = DriverProcess(prefix, master_domain, [
        ('port', port), ('arm', ARM), ('force_enabled_at_start', 'true'),
        ('loop_rate_hz', 1000.0), ('publish_decimation', PUBLISH_DECIMATION),
        ('passivity', on)])
    slave = DriverProcess(prefix, slave_domain, [
        ('centre_at_start', 'false'), ('centre', vector(HOME)), ('offset', vector(HOME)),
        ('box.stiffness', 0.0), ('wall.point', vector(wall_point)),
        ('wall.normal', vector(NORMAL)), ('passivity', on),
        *((name, float(value)) for name, value in SLAVE.items())],
        name='kraft_master_slave_sim')
    relay = subprocess.Popen(
        [sys.executable, str(RELAY), str(master_domain),
         str(slave_domain), str(round_trip_ms / 2.0), str(loss), str(seed)],
        env=installed_env(prefix, master_domain), stdout=subprocess.PIPE, text=True)
    master = Recorder(master_domain, 'bench_master', (
        ('master_energy', Vector3Stamped), ('diagnostics', DiagnosticArray)))
    far = Recorder(slave_domain, 'bench_slave', (
        ('slave_pose', PoseStamped), ('wrench', WrenchStamped),
        ('slave_energy', Vector3Stamped), ('diagnostics', DiagnosticArray)))
    samples = []
    sampling = threading.Event()

    def sample():
        scale = np.array(DEFAULT_TORQUE_SCALE, dtype=float)
        while not sampling.wait(0.002):
            theta = simulator.joint_angles()
            counts = np.array(simulator.received[-1][1].counts if simulator.received else [0] * 5)
            samples.append((time.monotonic(), theta, counts / scale))

    sampler = threading.Thread(target=sample, daemon=True)
    try:
        assert relay.stdout.readline().strip() == 'ready'
        deadline = time.monotonic() + 60.0
        while not (far.messages['slave_pose'] and master.messages['master_energy']
                   and far.messages['slave_energy']):
            assert time.monotonic() < deadline, 'driver, slave or relay did not start'
            time.sleep(0.05)
        sampler.start()
        home, pushed = joints_to_actuators(HOME_THETA), actuator_target(WALL_BELOW + PAST)
        marks = {}
        for phase, start, end, seconds in (('push', home, pushed, RAMP),
                                           ('hold', pushed, pushed, HOLD),
                                           ('release', pushed, home, RAMP),
                                           ('settle', home, home, SETTLE)):
            marks[phase] = t0 = time.monotonic()
            while (elapsed := time.monotonic() - t0) < seconds:
                blend = 0.5 - 0.5 * math.cos(math.pi * elapsed / seconds)
                simulator.hold_at(start + blend * (end - start))
                time.sleep(0.01)
        marks['end'] = time.monotonic()
        sampling.set()
        sampler.join()
        for recorder in (master, far):
            recorder.side.executor.shutdown()
        return figures(samples, master, far, marks, wall_point)
    finally:
        sampling.set()
        for started in (driver, slave):
            started.kill()
        relay.terminate()
        relay.communicate(timeout=20)
        master.side.close()
        far.side.close()
        simulator.stop()


def figures(samples, master, far, marks, wall_point):
    """Return the row's figures from what was recorded."""
    times = np.array([s[0] for s in samples])
    thetas = np.array([s[1] for s in samples])
    positions = kinematics.forward(thetas, ARM)[:, :3, 3]
    depths = (wall_point - positions) @ NORMAL
    window = (times >= marks['release'] - WINDOW) & (times < marks['release'])
    felt = []
    for theta, torques in zip(thetas[window], (s[2] for s, w in zip(samples, window) if w)):
        joint = np.array([torques[0], torques[1] + torques[2], *torques[2:]])
        jacobian = kinematics.jacobian(theta, ARM)
        felt.append(np.linalg.lstsq(jacobian[:3, :5].T, joint, rcond=None)[0] @ NORMAL)
    slave_at = [(t, xyz(m.pose.position)) for t, m in far.messages['slave_pose']]
    slave_depth = max((wall_point - p) @ NORMAL for _, p in slave_at)
    slave_force = [xyz(m.wrench.force) @ NORMAL for t, m in far.messages['wrench']
                   if marks['release'] - WINDOW <= t < marks['release']]
    energies = [m.vector for _, m in (master.messages['master_energy'][-1],
                                      far.messages['slave_energy'][-1])]
    generated = sum(e.y for e in energies) - sum(e.x for e in energies)
    drift = np.linalg.norm(slave_at[-1][1] - positions[-1])
    hold = marks['hold']
    ours = diagnostics_values(master.messages['diagnostics'], hold)
    theirs = diagnostics_values(far.messages['diagnostics'], hold)
    force_at_slave = float(np.mean(slave_force)) if slave_force else math.nan
    force_felt = float(np.mean(felt)) if felt else math.nan
    return {
        'master_pp_mm': 1e3 * float(np.ptp(depths[window])),
        'master_depth_mm': 1e3 * float(np.mean(depths[window])),
        'slave_penetration_mm': 1e3 * float(slave_depth),
        'energy_generated_j': float(generated),
        'dissipated_master_j': float(energies[0].z),
        'dissipated_slave_j': float(energies[1].z),
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
