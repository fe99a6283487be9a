#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The teleoperation loop of benchmarks/delay.py in simulated time: exact delays, no machine.

The same pieces as the live run, stepped in one process: the simulator's DeviceModel (device
and operator's hand), the driver's VelocityFilter, ForceReflection and MasterPort at 1 kHz, the
slave simulator's SlaveArm and SlavePort at 500 Hz, and between them a delay line holding each
message exactly half the round trip and dropping the given fraction. What it shows is the
physics of the loop without the scheduling of a loaded machine: where plain J^T F starts to
oscillate, and what passivity does. Figures, no asserts; the same columns as delay.py where
they exist.
"""
import argparse
import collections
import json
import math
import pathlib
import random
import sys

from kraft_master_driver.core import kinematics
from kraft_master_driver.core.force_reflection import ForceReflection
from kraft_master_driver.core.passivity import MasterPort, SlavePort
from kraft_master_driver.core.velocity_filter import VelocityFilter
from kraft_master_driver.core.wrench_admission import BASE_FRAME, WrenchAdmission
from kraft_master_driver.simulation.arms.point_mass import (
    SlaveArm, SlaveLimits, Wall)
from kraft_master_driver.simulation.master.model import (
    DEFAULT_DYNAMICS, DeviceModel, joints_to_actuators, Workspace)
import numpy as np

ARM = 'right'
LENGTHS = kinematics.LinkLengths(*kinematics.NOMINAL_LENGTHS)
MASTER_DT, SLAVE_DT = 0.001, 0.002  # s
WALL_BELOW, PAST = 0.03, 0.025  # m, as in test/harness/remote_session.py
RAMP, HOLD, WINDOW, SETTLE = 1.0, 5.0, 2.0, 2.0  # s
SLAVE = SlaveLimits(max_acceleration=100.0)


def actuator_target(home, depth):
    """Return the actuator coordinates with the wrist `depth` m below home."""
    theta = home.copy()
    goal = kinematics.forward(home, ARM)[:3, 3] - (0.0, 0.0, depth)
    for _ in range(20):
        pose, jacobian = kinematics.forward_and_jacobian(theta, ARM)
        theta[:3] += np.linalg.lstsq(jacobian[:3, :3], goal - pose[:3, 3], rcond=None)[0]
    return joints_to_actuators(theta)


def run(round_trip_ms, loss, passivity, seed=0, slave=SLAVE, force_scale=1.0):
    """Run one push, hold and release; return the row's figures."""
    rng = random.Random(seed)
    home = Workspace().home()
    start, pushed = joints_to_actuators(home), actuator_target(home, WALL_BELOW + PAST)
    model = DeviceModel(DEFAULT_DYNAMICS, home)
    home_position = kinematics.forward(home, ARM)[:3, 3]
    wall = Wall(home_position - (0.0, 0.0, WALL_BELOW), (0.0, 0.0, 1.0), 20000.0, 100.0)
    arm = SlaveArm(slave, wall)
    arm.reset(home_position)
    reflection = ForceReflection(force_scale=force_scale, enabled=True)
    admission = WrenchAdmission()
    velocity_filter = VelocityFilter(50.0)
    master_port, slave_port = MasterPort(), SlavePort()
    master_port.enabled = slave_port.enabled = passivity
    one_way = round_trip_ms / 2e3
    to_slave, to_master = collections.deque(), collections.deque()
    target = home_position.tolist()
    previous = None
    force = np.zeros(3)
    phases = ((start, pushed, RAMP), (pushed, pushed, HOLD), (pushed, start, RAMP),
              (start, start, SETTLE))
    total = sum(p[2] for p in phases)
    hold_end = RAMP + HOLD
    log = []
    next_slave = 0.0
    for k in range(int(total / MASTER_DT)):
        t = k * MASTER_DT
        phase_start = 0.0
        for begin, end, seconds in phases:
            if t < phase_start + seconds:
                blend = 0.5 - 0.5 * math.cos(math.pi * (t - phase_start) / seconds)
                hand = (begin + blend * (end - begin)).tolist()
                break
            phase_start += seconds
        theta = model.joint_angle_list()
        pose, entries = kinematics.forward_and_jacobian_entries(theta, ARM, LENGTHS)
        jacobian = [entries[row:row + 6] for row in range(0, 36, 6)]
        velocity = velocity_filter.update(theta, round(t * 1e9))
        twist = [sum(a * b for a, b in zip(row, velocity)) for row in jacobian]
        if previous is not None:
            step = [a - b for a, b in zip(theta, previous)]
            master_port.moved([sum(a * b for a, b in zip(row, step)) for row in jacobian])
        previous = theta
        position = [pose[3], pose[7], pose[11]]
        if rng.random() >= loss:
            to_slave.append((t + one_way, position, master_port.energy_in))
        while to_master and to_master[0][0] <= t:
            _, reflected, energy = to_master.popleft()
            reflection.hold(admission.admit(tuple(reflected) + (0.0, 0.0, 0.0), BASE_FRAME,
                                            0, round(t * 1e9), 0))
            master_port.credit(energy)
        out = reflection.compute((pose[0:3], pose[4:7], pose[8:11]), jacobian, round(t * 1e9),
                                 cartesian_velocity=twist, port=master_port)
        model.motor[:5] = list(out.actuator)
        model.step(MASTER_DT, hand)
        while next_slave <= t + 1e-12:
            while to_slave and to_slave[0][0] <= t:
                _, target, energy = to_slave.popleft()
                slave_port.credit(energy)
            command = slave_port.step(target, arm.contact_force().tolist(), SLAVE_DT)
            force = arm.advance(SLAVE_DT, target=np.array(command))
            if rng.random() >= loss:
                to_master.append((t + one_way, force.tolist(), slave_port.energy_in))
            next_slave += SLAVE_DT
        felt = _felt(theta, out.actuator)
        log.append((t, wall.penetration(np.array(position)), wall.penetration(arm.position),
                    force[2], felt, *arm.position, *position))
    log = np.array(log)
    window = (log[:, 0] >= hold_end - WINDOW) & (log[:, 0] < hold_end)
    generated = (master_port.energy_out + slave_port.energy_out
                 - master_port.energy_in - slave_port.energy_in)
    force_slave, force_felt = log[window, 3].mean(), log[window, 4].mean()
    return {
        'master_pp_mm': 1e3 * float(np.ptp(log[window, 1])),
        'master_depth_mm': 1e3 * float(log[window, 1].mean()),
        'slave_penetration_mm': 1e3 * float(log[:, 2].max()),
        'energy_generated_j': float(generated),
        'dissipated_master_j': master_port.dissipated,
        'dissipated_slave_j': slave_port.dissipated,
        'force_slave_n': float(force_slave),
        'force_felt_n': float(force_felt),
        'felt_ratio': float(force_felt / force_slave) if force_slave else math.nan,
        'drift_mm': 1e3 * float(np.linalg.norm(log[-1, 5:8] - log[-1, 8:11])),
    }


def _felt(theta, actuator):
    """Return the force along +z that the torques sent amount to at the wrist (N)."""
    t1, t2, t3, t4, t5 = actuator
    joint = np.array([t1, t2 + t3, t3, t4, t5])
    jacobian = kinematics.jacobian(theta, ARM)
    return float(np.linalg.lstsq(jacobian[:3, :5].T, joint, rcond=None)[0][2])


COLUMNS = (('rtt ms', 'round_trip_ms', '{:.0f}'), ('loss %', 'loss_pct', '{:.0f}'),
           ('passivity', 'passivity', '{}'), ('master p-p mm', 'master_pp_mm', '{:.2f}'),
           ('slave pen. mm', 'slave_penetration_mm', '{:.2f}'),
           ('channel E J', 'energy_generated_j', '{:+.4f}'),
           ('F slave N', 'force_slave_n', '{:.2f}'), ('F felt N', 'force_felt_n', '{:.2f}'),
           ('felt/slave', 'felt_ratio', '{:.3f}'), ('drift mm', 'drift_mm', '{:.2f}'))


def main(argv=None):
    """Run the rows, print the table, write JSON if asked."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--round-trips', type=float, nargs='+',
                        default=(0, 20, 30, 50, 100, 250, 500))
    parser.add_argument('--losses', type=float, nargs='+', default=(0.0, 0.01, 0.1))
    parser.add_argument('--passivity', choices=('off', 'on', 'both'), default='both')
    parser.add_argument('--json', type=pathlib.Path, help='write the rows here')
    args = parser.parse_args(argv)
    modes = {'off': (False,), 'on': (True,), 'both': (False, True)}[args.passivity]
    rows = []
    print(' | '.join(title for title, _, _ in COLUMNS), flush=True)
    for round_trip in args.round_trips:
        for loss in args.losses:
            for passivity in modes:
                row = {'round_trip_ms': round_trip, 'loss_pct': 100.0 * loss,
                       'passivity': 'on' if passivity else 'off',
                       **run(round_trip, loss, passivity)}
                rows.append(row)
                print(' | '.join(form.format(row[key]) for _, key, form in COLUMNS),
                      flush=True)
    if args.json:
        args.json.write_text(json.dumps({'slave': SLAVE._asdict(), 'rows': rows}, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
