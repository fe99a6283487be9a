# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Gravity compensation against the simulator whose links weigh, the hand off.

The masses are made up; the mechanics run in lockstep with the commands (simulated time: the
same figures on a busy machine).

Identifies the base parameters as `kraft_master_calibrate --identify-gravity` does, then prints
how far the identified holding torques are from the simulator's true ones (at the release
poses and at random poses) and how far the wrist drifts in 2 s when released at each of ten
poses with only the compensation, and without it.

    .venv/bin/python benchmarks/gravity.py [--runs N]
"""
import argparse

from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration
from kraft_master_driver.core.gravity import GravityModel
from kraft_master_driver.link.device import KmcDevice
from kraft_master_driver.simulation.master.model import HAND_OFF
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
from kraft_master_driver.tools import gravity_identification
from kraft_master_driver.tools.gravity_identification import PdHold, POSES_DEG
from kraft_master_driver.tools.torque_check import CYCLE_PERIOD
import numpy as np

RELEASE_POSES = POSES_DEG[:10]


def one_run(seed):
    """Identify, then release; return (torque errors as fractions, drifts in m)."""
    model = GravityModel('right')
    simulator = SimulatedKraftMaster(arm='right', dynamics=HAND_OFF, gravity=True,
                                     pot_noise_counts=1.0, seed=seed, lockstep=CYCLE_PERIOD)
    with simulator, KmcDevice(simulator.port) as device:
        hold = PdHold(device, ArmCalibration.nominal('right'))
        result = gravity_identification.identify(hold, model, log=lambda line: None)
        for line in gravity_identification.describe(result):
            print(f'  run {seed}: {line}')
        rng = np.random.default_rng(seed)
        poses = [gravity_identification.joints_of(gravity_identification.actuators_of(pose))
                 for pose in RELEASE_POSES]
        poses += list(rng.uniform(kinematics.JOINT_LIMITS[:, 0], kinematics.JOINT_LIMITS[:, 1],
                                  (50, 6)))
        errors = []
        for theta in poses:
            true = np.array(simulator.holding_torques(theta))
            errors.append(np.abs(model.holding_torques(theta, result.base) - true).max()
                          / np.abs(true).max())
        drifts = [gravity_identification.release_drift(hold, model, result.base, pose)
                  for pose in RELEASE_POSES]
    return np.array(errors), np.array(drifts)


def main():
    """Run and print the distributions."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--runs', type=int, default=3, help='identifications (seeds)')
    args = parser.parse_args()
    errors, drifts = [], []
    for seed in range(args.runs):
        run_errors, run_drifts = one_run(seed)
        errors.append(run_errors)
        drifts.append(run_drifts)
    errors, drifts = np.concatenate(errors), np.concatenate(drifts) * 1000.0
    print(f'identified torque error / true torque (largest axis), {len(errors)} poses: '
          f'median {np.median(errors):.4f}, p95 {np.percentile(errors, 95):.4f}, '
          f'max {errors.max():.4f} (target <= 0.05)')
    print(f'drift in 2 s released at {len(drifts)} poses, compensated (mm): median '
          f'{np.median(drifts):.2f}, p95 {np.percentile(drifts, 95):.2f}, max {drifts.max():.2f} '
          '(target <= 5)')


if __name__ == '__main__':
    main()
