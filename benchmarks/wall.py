#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The stiffest wall the simulated Kraft Master renders still, through its pot counts.

Colgate and Schenkel's bound for a sampled wall, K < 2 (b - |B|) / T, with b the device's own
damping in its least damped direction (the simulated device's, DEFAULT_DYNAMICS, over poses
around home) gives the stiffness the driver clips a contact model to (device_damping,
core/contact_rendering.py). Beside it, measured: the driver's force path renders a wall of each
stiffness under the wrist (no clip), the loop at 1 or 2 kHz reads the angles through whole pot
counts of the nominal calibration, and the simulator's operator's hand (its spring and damping)
aims 15 mm past the wall. The wall keeps its books (a wall that would generate energy fades
instead): each cell gives the wrist's peak-to-peak along the normal and the stiffness felt
(force over depth) over the last second of five; rendered is still (at most 0.5 mm) and felt at
0.9 of its stiffness at least. The hand's damping is far above the device's, so this is not the
bound's case (the hand let go), which the clip keeps to. Simulated time: the figures do not
depend on how busy the machine is.
"""
import argparse
import sys

from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration
from kraft_master_driver.core.contact_model import ContactModel
from kraft_master_driver.core.contact_rendering import (
    ContactRenderer, renderable_stiffness, RendererSettings)
from kraft_master_driver.core.force_mode import (
    ForceMode, ModelFeedback, ModeSelector, ModeSettings)
from kraft_master_driver.core.force_reflection import ACTIVE, ForceReflection
from kraft_master_driver.core.velocity_filter import VelocityFilter
from kraft_master_driver.simulation.master.model import (
    DEFAULT_DYNAMICS, DeviceModel, joints_to_actuators, Workspace)
import numpy as np

ARM = 'right'
SECONDS, WINDOW = 5.0, 1.0
STILL = 0.0005  # m peak-to-peak
DEPTH = 0.015  # m past the wall the hand aims


def least_damping(samples=50, spread=0.3, seed=0):
    """Return the device's least Cartesian damping (N*s/m) over poses around home."""
    rng = np.random.default_rng(seed)
    coupling = np.eye(6)
    coupling[2, 1] = 1.0  # actuator 3 turns th2 + th3
    joint = coupling.T @ np.diag(DEFAULT_DYNAMICS.damping) @ coupling
    home = Workspace().home()
    least = np.inf
    for theta in [home] + [home + rng.uniform(-spread, spread, 6) for _ in range(samples)]:
        inverse = np.linalg.inv(kinematics.jacobian(theta, ARM)[:3, :3])
        least = min(least, np.linalg.eigvalsh(inverse.T @ joint[:3, :3] @ inverse).min())
    return float(least)


def _hand_target(home_theta, depth):
    """Return actuator coordinates that put the wrist `depth` m below home."""
    theta = home_theta.copy()
    goal = kinematics.forward(home_theta, ARM)[:3, 3] - depth * np.array([0.0, 0.0, 1.0])
    for _ in range(20):
        pose, jacobian = kinematics.forward_and_jacobian(theta, ARM)
        theta[:3] += np.linalg.lstsq(jacobian[:3, :3], goal - pose[:3, 3], rcond=None)[0]
    return joints_to_actuators(theta).tolist()


def on_the_wall(stiffness, rate_hz):
    """
    Return the wrist's peak-to-peak (m) and the stiffness felt (N/m) on a wall of `stiffness`.

    Both over the last WINDOW s, the wall rendered at `rate_hz` with its books (a wall that
    would generate energy fades instead: then it is still, and softer).
    """
    period = 1.0 / rate_hz
    home_theta = Workspace().home()
    device = DeviceModel(DEFAULT_DYNAMICS, home_theta)
    calibration = ArmCalibration.nominal(ARM)
    wall_z = kinematics.forward(home_theta, ARM)[2, 3]
    renderer = ContactRenderer(RendererSettings(rate_hz=rate_hz, device_damping=1e6))
    feedback = ModelFeedback(ModeSelector(ModeSettings(ForceMode.MODEL)), renderer)
    reflection = ForceReflection(enabled=True)
    velocity_filter = VelocityFilter(50.0)
    target = _hand_target(home_theta, DEPTH)
    heights, forces = [], []
    steps = round(SECONDS * rate_hz)
    for step in range(steps):
        now_ns = round(step * period * 1e9)
        theta = calibration.frame_to_joints(
            [round(count) for count in calibration.joints_to_frame(device.joint_angle_list())])
        pose, entries = kinematics.forward_and_jacobian_entries(theta, ARM)
        jacobian = [entries[row:row + 6] for row in range(0, 36, 6)]
        velocity = velocity_filter.update(theta, now_ns)
        twist = [sum(a * b for a, b in zip(row, velocity)) for row in jacobian]
        # The wall's model, sent again as the arm's side repeats it.
        feedback.take(ContactModel((0.0, 0.0, wall_z), (0.0, 0.0, 1.0), stiffness, 0.0, 1.0,
                                   True), now_ns)
        out = reflection.compute((pose[0:3], pose[4:7], pose[8:11]), jacobian, now_ns,
                                 cartesian_velocity=twist,
                                 model=feedback.force((pose[3], pose[7], pose[11]),
                                                      twist[:3], now_ns))
        feedback.applied(out.model_share if out.state == ACTIVE else 0.0)
        device.motor[:5] = list(out.actuator)
        device.step(period, target)
        if step >= steps - round(WINDOW * rate_hz):
            heights.append(pose[11])
            forces.append(renderer._force[2])
    depth = wall_z - float(np.mean(heights))
    return float(np.ptp(heights)), float(np.mean(forces)) / depth if depth > 0 else np.nan


def main(argv=None):
    """Print the bound and the measured stiffest still wall at each rate."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--rates', type=float, nargs='+', default=(1000.0, 2000.0))
    parser.add_argument('--stiffnesses', type=float, nargs='+',
                        default=(250, 500, 750, 1000, 1500, 2000, 3000, 4000, 6000, 8000))
    args = parser.parse_args(argv)
    damping = least_damping()
    print(f"the device's least damping: {damping:.3f} N*s/m")
    print('each cell: peak-to-peak mm / stiffness felt N/m')
    print('rate Hz | bound N/m | ' + ' | '.join(f'{k:g}' for k in args.stiffnesses)
          + ' | stiffest still and felt at 0.9, N/m')
    for rate in args.rates:
        bound = renderable_stiffness(rate, damping)
        cells = [on_the_wall(k, rate) for k in args.stiffnesses]
        still = [k for k, (spread, felt) in zip(args.stiffnesses, cells)
                 if spread <= STILL and felt >= 0.9 * k]
        stiffest = f'{max(still):g}' if still else 'none'
        print(f'{rate:g} | {bound:.0f} | '
              + ' | '.join(f'{1e3 * spread:.2f} / {felt:.0f}' for spread, felt in cells)
              + f' | {stiffest}', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
