#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Render the simulated Panda pressing on its table, offscreen with MuJoCo's renderer (doc/figures/).

Runs simulation.arms.panda.PandaArm alone (no ROS): from the ready pose its target goes down
at 0.1 m/s to 2 cm below the table top, and the arm is held there for 2 s; then one frame is
rendered, with the contact force drawn as an arrow, and the figures of that moment printed:
where the fingertips are, the table's force on them, and the sensor's reading less the tool's
weight. Needs an OpenGL for offscreen use: MUJOCO_GL=egl (Debian's libegl1 with Mesa) or
MUJOCO_GL=osmesa (libosmesa6); the script sets egl unless MUJOCO_GL is set.
"""
import argparse
import os
import pathlib
import sys

os.environ.setdefault('MUJOCO_GL', 'egl')
from kraft_master_driver.simulation.arms.panda import PandaArm, Table  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
GRAVITY = np.array([0.0, 0.0, -9.81])
SPEED = 0.1  # m/s of the target, down
PAST_THE_TOP = 0.02  # m


def press(arm):
    """Drive the target down through the table top and hold it; return the contact figures."""
    start = arm.tool_position()
    quaternion = arm.tool_quaternion()
    depth = start[2] - Table().height + PAST_THE_TOP
    dt = arm.model.opt.timestep
    for step in range(round((depth / SPEED + 2.0) / dt)):
        drop = min(SPEED * step * dt, depth)
        arm.command_pose(start - (0.0, 0.0, drop), quaternion, arm.time)
        arm.step()
    mass, _ = arm.tool_mass_properties()
    reading = arm.sensor_rotation() @ arm.wrench()[:3] - mass * GRAVITY
    return arm.tool_position(), arm.table_contact_force(), reading


def render(arm, width, height):
    """Return the frame (height x width x 3) seen by a camera in front of the arm."""
    camera = mujoco.MjvCamera()
    camera.lookat[:] = (0.25, 0.0, 0.4)
    camera.distance, camera.azimuth, camera.elevation = 1.5, 115.0, -12.0
    options = mujoco.MjvOption()
    options.flags[mujoco.mjtVisFlag.mjVIS_CONTACTFORCE] = True
    arm.model.vis.map.force = 0.03  # m of arrow per N
    arm.model.vis.scale.forcewidth = 0.02
    with mujoco.Renderer(arm.model, height, width) as renderer:
        renderer.update_scene(arm.data, camera, options)
        return renderer.render()


def main():
    """Render the contact and write the PNG; print the figures of the moment shown."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('output', nargs='?', default=str(HERE / 'arm_contact.png'))
    parser.add_argument('--width', type=int, default=960)
    parser.add_argument('--height', type=int, default=720)
    args = parser.parse_args()
    arm = PandaArm()
    tip, contact, reading = press(arm)
    Image.fromarray(render(arm, args.width, args.height)).save(args.output)
    print(f'{args.output}: fingertips at {np.round(tip, 4).tolist()} m; table force on them '
          f'{np.round(contact, 2).tolist()} N; sensor less tool weight, base frame '
          f'{np.round(reading, 2).tolist()} N')
    return 0


if __name__ == '__main__':
    sys.exit(main())
