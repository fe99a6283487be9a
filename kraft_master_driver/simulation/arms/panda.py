# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
A Franka Emika Panda in MuJoCo, under a Cartesian impedance controller, touching a table: no ROS.

The arm's model (its kinematic chain, inertias, joint ranges and meshes) is the Panda MJCF that
the PyPI package gymnasium-robotics ships (Apache-2.0, after Vikash Kumar's franka model); it is
read from the installed package, never downloaded. build_model() includes its files by path and
changes, in memory only: the hand and the closed fingers become one rigid tool body hung from a
wrist force/torque sensor at the flange, the joints get torque motors at Franka's torque limits,
the joints' damping is ours (the package's 100 N*m*s/rad suits its position servos, not torque
control), and a table stands in front of the arm.

PandaArm steps it: each 1 ms step, the controller (in the manner of franka_example_controllers'
cartesian_impedance_example_controller) computes

    tau = J^T (-K e - D J dq) + (I - J^T J^T+) (k_n (q_n - q) - 2 sqrt(k_n) dq) + c(q, dq) + g(q)

with e the tool's pose error (position and rotation vector, arm base frame), D = 2 zeta sqrt(K),
the nullspace pulling toward the posture q_n, and Coriolis and gravity compensated as a Franka
does by itself; the change of tau is limited to Franka's 1000 N*m/s and tau to its joint torque
limits. MuJoCo enforces the joint ranges. The target comes from command_pose() (servo_cp) or is
moved by command_twist() (servo_cv); a command command_timeout old or older, or none, holds
the arm still where it is measured.
"""
import importlib.util
import math
import pathlib
from typing import NamedTuple

from kraft_master_driver.core.rotations import (
    clamp_norm, quaternion_to_rotation, QUATERNION_TOLERANCE, rotation_from_vector,
    rotation_to_quaternion)
import mujoco
import numpy as np

ASSETS = ('envs', 'assets', 'kitchen_franka', 'franka_assets')
JOINTS = tuple(f'robot:panda0_joint{i}' for i in range(1, 8))
JOINT_NAMES = tuple(f'panda_joint{i}' for i in range(1, 8))
TORQUE_LIMITS = np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0])  # N*m, Franka's datasheet
TORQUE_RATE_LIMIT = 1000.0  # N*m/s, as franka_example_controllers limit it (1 N*m per 1 ms)
# rad: the ready pose, hand down (this model's joints 6 and 7 are zero where Franka's are at
# about pi/2 and pi/4)
HOME = (0.0, -0.785, 0.0, -2.356, 0.0, 0.0, 0.0)
TIMESTEP = 0.001  # s
TOOL_TIP = 0.153  # m from the flange along the hand's z: the bottom of the closed fingertips
# kg*m^2 at each joint: a geared motor's reflected inertia, which the package's model leaves
# out. Without it the wrist's last joint (about 3e-3 kg*m^2) chattered at half the step rate
# under the rotational damping.
ARMATURE = 0.1
TABLE_TOP_THICKNESS = 0.03  # m
TABLE_TOP_MASS = 1.0  # kg: with the default spring and damping, 23 Hz, damping ratio 0.35
SINGULARITY_GUARD = 1e-6 * np.eye(6)  # m^2 added to J J^T's diagonal
# s: ROS time's resolution. A command's age is compared to command_timeout to within it, so
# the rounding of a clock summed 1 ms at a time (1e-14 s at 1 s, 1e-11 s at 10 s) cannot
# decide whether a command exactly command_timeout old is stale.
CLOCK_RESOLUTION = 1e-9


class ArmModelMissing(RuntimeError):
    """The Panda's model is not installed (the PyPI package gymnasium-robotics)."""


def franka_assets():
    """Return the directory of the Panda MJCF inside the installed gymnasium-robotics."""
    spec = importlib.util.find_spec('gymnasium_robotics')
    if spec is None or not spec.submodule_search_locations:
        raise ArmModelMissing('the Panda model comes from the PyPI package gymnasium-robotics, '
                              'which is not installed: pip install gymnasium-robotics')
    path = pathlib.Path(spec.submodule_search_locations[0]).joinpath(*ASSETS)
    if not (path / 'chain.xml').is_file():
        raise ArmModelMissing(f'{path}/chain.xml is missing: this gymnasium-robotics has no '
                              'Panda model where version 1.4 has it')
    return path


def _finite(name, values, count):
    array = np.asarray(values, dtype=float)
    if array.shape != (count,) or not np.all(np.isfinite(array)):
        raise ValueError(f'{name} must be {count} finite numbers, got {list(values)}')
    return array


def _positive(name, value, allow_zero=False):
    if not (math.isfinite(value) and (value >= 0.0 if allow_zero else value > 0.0)):
        raise ValueError(f'{name} must be finite and {">=" if allow_zero else ">"} 0, '
                         f'got {value}')
    return float(value)


class Table(NamedTuple):
    """A box in front of the arm: where its top is, its size and how hard it is (SI units)."""

    centre: tuple = (0.5, 0.0)  # m, x and y of the top's middle, arm base frame
    half_sizes: tuple = (0.25, 0.4)  # m, along x and y
    height: float = 0.4  # m, z of the top: 37 mm below the fingertips at HOME
    stiffness: float = 20000.0  # N/m of the top's spring
    damping: float = 100.0  # N*s/m of the top's spring
    friction: float = 0.5

    def checked(self):
        """Return the table with its values checked, else raise ValueError naming the bad one."""
        _finite('table.centre', self.centre, 2)
        half = _finite('table.half_sizes', self.half_sizes, 2)
        if not np.all(half > 0.0):
            raise ValueError(f'table.half_sizes must be > 0, got {list(self.half_sizes)}')
        if not (math.isfinite(self.height) and 0.05 <= self.height <= 1.5):
            raise ValueError(f'table.height must be within 0.05 .. 1.5 m, got {self.height}')
        _positive('table.stiffness', self.stiffness)
        _positive('table.damping', self.damping, allow_zero=True)
        _positive('table.friction', self.friction, allow_zero=True)
        return self


class Gains(NamedTuple):
    """The impedance: stiffness (N/m, N*m/rad), damping ratio, nullspace, joint damping."""

    translational_stiffness: float = 1000.0
    rotational_stiffness: float = 30.0
    damping_ratio: float = 1.0
    nullspace_stiffness: float = 1.0
    joint_damping: float = 0.5  # N*m*s/rad at each joint: the gears' viscous friction
    max_position_error: float = 0.1  # m: a farther target pulls as if this far
    max_rotation_error: float = 0.5  # rad

    def checked(self):
        """Return the gains, each finite and >= 0 (stiffnesses > 0), else raise ValueError."""
        for name, value in zip(self._fields, self):
            _positive(name, value, allow_zero=name in ('nullspace_stiffness', 'joint_damping'))
        return self


class SensorModel(NamedTuple):
    """The F/T sensor's faults: a constant bias (N, N*m) and white noise (standard deviation)."""

    force_bias: tuple = (0.0, 0.0, 0.0)
    torque_bias: tuple = (0.0, 0.0, 0.0)
    force_noise: float = 0.0
    torque_noise: float = 0.0

    def checked(self):
        """Return the sensor model with its values checked, else raise ValueError."""
        _finite('force_bias', self.force_bias, 3)
        _finite('torque_bias', self.torque_bias, 3)
        _positive('force_noise', self.force_noise, allow_zero=True)
        _positive('torque_noise', self.torque_noise, allow_zero=True)
        return self


def _mjcf(assets):
    """Our scene's MJCF: the package's asset and chain files included by path."""
    return f"""<mujoco model="panda_at_a_table">
  <include file="{assets / 'assets.xml'}"/>
  <compiler angle="radian" meshdir="{assets / 'meshes'}"/>
  <option timestep="{TIMESTEP}" integrator="implicitfast"/>
  <visual><global offwidth="1280" offheight="960"/></visual>
  <worldbody>
    <light pos="0.6 -1.0 2.0" dir="-0.3 0.5 -1" diffuse="0.7 0.7 0.7"/>
    <light pos="-0.5 1.0 2.5" dir="0.4 -0.4 -1" diffuse="0.4 0.4 0.4"/>
    <geom name="floor" type="plane" size="2 2 0.01" rgba="0.55 0.6 0.65 1"
          contype="0" conaffinity="0"/>
    <include file="{assets / 'chain.xml'}"/>
  </worldbody>
</mujoco>"""


def build_model(table=Table(), gains=Gains()):
    """Return the MjModel of the Panda with its F/T sensor and tool, at `table`."""
    table, gains = table.checked(), gains.checked()
    spec = mujoco.MjSpec.from_string(_mjcf(franka_assets()))
    link7 = spec.body('panda0_link7')
    hand_geoms = [g for g in link7.geoms if g.meshname in ('hand_viz', 'hand_col')]
    hand_pos, hand_quat = np.array(hand_geoms[0].pos), np.array(hand_geoms[0].quat)
    finger = spec.body('panda0_leftfinger')
    finger_offset = float(finger.pos[2] - hand_pos[2])  # the fingers' base, hand frame
    finger_viz = next(g for g in finger.geoms if g.meshname == 'finger_viz')
    finger_rgba = np.array(finger_viz.rgba)
    for geom in hand_geoms:
        spec.delete(geom)
    for name in ('panda0_leftfinger', 'panda0_rightfinger'):
        spec.delete(spec.body(name))
    for site in list(link7.sites):
        spec.delete(site)

    # The tool: hand and closed fingers, rigid, below the sensor at the flange.
    tool = link7.add_body(name='tool', pos=hand_pos, quat=hand_quat)
    tool.add_site(name='ft_sensor', size=[0.01, 0.01, 0.01], rgba=[0.9, 0.5, 0.1, 1])
    tool.add_site(name='tcp', pos=[0, 0, TOOL_TIP], size=[0.005, 0.005, 0.005],
                  rgba=[0.1, 0.6, 0.1, 1])
    visual = {'contype': 0, 'conaffinity': 0, 'group': 0, 'mass': 0.0,
              'rgba': [0.95, 0.99, 0.92, 1]}
    tool.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname='hand_viz', **visual)
    tool.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname='hand_col', group=3,
                  mass=0.81909, rgba=[0.5, 0.6, 0.7, 1])
    for side, quat in ((1.0, [1, 0, 0, 0]), (-1.0, [0, 0, 0, 1])):
        tool.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname='finger_viz',
                      pos=[0, 0, finger_offset], quat=quat,
                      **{**visual, 'rgba': finger_rgba})
        # The closed fingertip pads, for contact; mass as the package's finger inertial's.
        tool.add_geom(name=f'fingertip_{"left" if side > 0 else "right"}',
                      type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.0185, 0.006, 0.025],
                      pos=[0, side * 0.007, TOOL_TIP - 0.025], mass=0.0927059, group=3,
                      rgba=[0.5, 0.6, 0.7, 1], friction=[table.friction, 0.005, 0.0001])
    spec.add_exclude(bodyname1='panda0_link6', bodyname2='tool')
    spec.add_sensor(name='ft_force', type=mujoco.mjtSensor.mjSENS_FORCE,
                    objtype=mujoco.mjtObj.mjOBJ_SITE, objname='ft_sensor')
    spec.add_sensor(name='ft_torque', type=mujoco.mjtSensor.mjSENS_TORQUE,
                    objtype=mujoco.mjtObj.mjOBJ_SITE, objname='ft_sensor')

    for joint_name, limit in zip(JOINTS, TORQUE_LIMITS):
        motor = spec.add_actuator(name=joint_name.split(':')[-1], target=joint_name,
                                  trntype=mujoco.mjtTrn.mjTRN_JOINT)
        motor.set_to_motor()
        motor.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        motor.ctrlrange = [-limit, limit]
        joint = spec.joint(joint_name)
        joint.damping = [gains.joint_damping, 0.0, 0.0]
        joint.armature = ARMATURE

    # The table: a top on a vertical spring (its stiffness and damping in N/m and N*s/m, as
    # given) over a fixed base. The fingertips meet the top through MuJoCo's default contact,
    # which yields about 0.1 mm: the spring is the table's compliance.
    height, (half_x, half_y), (centre_x, centre_y) = table.height, table.half_sizes, table.centre
    base = height - TABLE_TOP_THICKNESS
    spec.worldbody.add_geom(
        name='table_base', type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[half_x * 0.97, half_y * 0.97, base / 2.0], pos=[centre_x, centre_y, base / 2.0],
        rgba=[0.45, 0.32, 0.2, 1])
    top = spec.worldbody.add_body(name='table_top', gravcomp=1.0,
                                  pos=[centre_x, centre_y, height - TABLE_TOP_THICKNESS / 2.0])
    top.add_joint(name='table_spring', type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, 0, 1],
                  stiffness=[table.stiffness, 0.0, 0.0], damping=[table.damping, 0.0, 0.0])
    top.add_geom(name='table', type=mujoco.mjtGeom.mjGEOM_BOX, mass=TABLE_TOP_MASS,
                 size=[half_x, half_y, TABLE_TOP_THICKNESS / 2.0], rgba=[0.62, 0.45, 0.3, 1],
                 friction=[table.friction, 0.005, 0.0001])
    spec.add_exclude(bodyname1='world', bodyname2='table_top')
    return spec.compile()


class PandaArm:
    """The simulated Panda, its controller and its F/T sensor; step() advances 1 ms."""

    def __init__(self, table=Table(), gains=Gains(), sensor=SensorModel(),
                 command_timeout=0.1, seed=None):
        """Build the model and put the arm at rest at HOME, holding its pose there."""
        self.gains = gains.checked()
        self.sensor = sensor.checked()
        self.command_timeout = _positive('command_timeout', command_timeout)
        self.model = build_model(table, gains)
        self.data = mujoco.MjData(self.model)
        model = self.model
        self.joint_ids = [model.joint(name).id for name in JOINTS]
        # The arm's joints come first in the model (the table's spring after them): slices,
        # which index faster than arrays of indices.
        assert [model.jnt_dofadr[j] for j in self.joint_ids] == list(range(7))
        assert [model.jnt_qposadr[j] for j in self.joint_ids] == list(range(7))
        self.dof = self.qpos = slice(0, 7)
        self.joint_range = model.jnt_range[self.joint_ids].copy()
        self.tcp = model.site('tcp').id
        self.ft_site = model.site('ft_sensor').id
        self.tool_body = model.body('tool').id
        self.table_geom = model.geom('table').id
        self.table_spring = model.jnt_qposadr[model.joint('table_spring').id]
        self._force_adr = model.sensor_adr[model.sensor('ft_force').id]
        self._torque_adr = model.sensor_adr[model.sensor('ft_torque').id]
        self._rng = np.random.default_rng(seed)
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))
        self._jacobian = np.zeros((6, 7))
        self._error = np.zeros(6)
        self._quat = np.zeros(4)
        self._task_space = np.zeros(6)
        gains = self.gains
        self._stiffness = np.repeat([gains.translational_stiffness,
                                     gains.rotational_stiffness], 3)
        self._damping = 2.0 * gains.damping_ratio * np.sqrt(self._stiffness)
        self._null_stiffness = gains.nullspace_stiffness
        self._null_damping = 2.0 * math.sqrt(gains.nullspace_stiffness)
        self._rate_step = TORQUE_RATE_LIMIT * model.opt.timestep
        self.torque = np.zeros(7)  # the last command, gravity and Coriolis included
        self.task_torque = np.zeros(7)  # its part beyond gravity and Coriolis, rate-limited
        self.nullspace_posture = np.array(HOME)
        self.reset(HOME)

    # -- state -------------------------------------------------------------------------

    def reset(self, joints):
        """Put the arm at rest at `joints` (rad, 7) and hold its tool's pose there."""
        self.data.qpos[self.qpos] = _finite('joints', joints, 7)
        self.data.qvel[:] = 0.0
        mujoco.mj_forward(self.model, self.data)
        self.task_torque[:] = 0.0
        self.torque = self.data.qfrc_bias[self.dof].copy()
        self._pose_command = None  # (position, rotation, time)
        self._twist_command = None  # (linear, angular, time)
        self._hold()

    def _hold(self):
        """Make the measured pose the target: the arm stops where it is."""
        self.target_position, self.target_rotation = self.tool_position(), self.tool_rotation()
        self.holding = True

    @property
    def time(self):
        """Return how long the physics has run (s)."""
        return self.data.time

    def tool_position(self):
        """Return the tool point's position (m, arm base frame)."""
        return self.data.site_xpos[self.tcp].copy()

    def tool_rotation(self):
        """Return the tool frame's rotation matrix (arm base frame)."""
        return self.data.site_xmat[self.tcp].reshape(3, 3).copy()

    def tool_quaternion(self):
        """Return the tool's orientation as a unit quaternion x, y, z, w."""
        return tuple(float(v) for v in rotation_to_quaternion(self.tool_rotation()))

    def joint_positions(self):
        """Return the joint angles (rad, 7)."""
        return self.data.qpos[self.qpos].copy()

    def joint_velocities(self):
        """Return the joint velocities (rad/s, 7)."""
        return self.data.qvel[self.dof].copy()

    def tool_mass_properties(self):
        """Return the tool's mass (kg) and its centre of mass (m, sensor frame)."""
        body = self.tool_body
        return float(self.model.body_mass[body]), self.model.body_ipos[body].copy()

    # -- commands ----------------------------------------------------------------------

    def command_pose(self, position, quaternion, now):
        """Take a target pose (m; x, y, z, w); return None, or the one line refusing it."""
        try:
            position = _finite('servo_cp position', position, 3)
            quaternion = _finite('servo_cp orientation', quaternion, 4)
        except ValueError as error:
            return str(error)
        length = float(np.linalg.norm(quaternion))
        if abs(length - 1.0) > QUATERNION_TOLERANCE:
            return f'servo_cp orientation {quaternion.tolist()} is not a unit quaternion'
        self._pose_command = (position, quaternion_to_rotation(quaternion / length), now)
        self._twist_command = None
        return None

    def command_twist(self, linear, angular, now):
        """Take a twist (m/s, rad/s, base frame); return None, or the one line refusing it."""
        try:
            linear = _finite('servo_cv linear', linear, 3)
            angular = _finite('servo_cv angular', angular, 3)
        except ValueError as error:
            return str(error)
        if self._twist_command is None:
            self._pose_command = None
            if not self.holding:
                self._hold()
        self._twist_command = (linear, angular, now)
        return None

    def _fresh(self, received, now):
        """Return whether a command received at `received` is younger than command_timeout."""
        return now - received < self.command_timeout - CLOCK_RESOLUTION

    def _update_target(self, now, dt):
        """Follow the fresh command; hold still where measured when it goes stale."""
        if self._pose_command is not None:
            position, rotation, received = self._pose_command
            if self._fresh(received, now):
                self.target_position, self.target_rotation = position, rotation
                self.holding = False
                return
            self._pose_command = None
        elif self._twist_command is not None:
            linear, angular, received = self._twist_command
            if self._fresh(received, now):
                self.target_position = self.target_position + linear * dt
                self.target_rotation = rotation_from_vector(angular * dt) @ self.target_rotation
                self.holding = False
                return
            self._twist_command = None
        if not self.holding:
            self._hold()

    # -- the controller and the step ---------------------------------------------------

    def _control(self):
        """Return the joint torques of the Cartesian impedance law (see the module's text)."""
        model, data, arm = self.model, self.data, self.dof
        jacobian, error, quat = self._jacobian, self._error, self._quat
        mujoco.mj_jacSite(model, data, self._jacp, self._jacr, self.tcp)
        jacobian[:3], jacobian[3:] = self._jacp[:, arm], self._jacr[:, arm]
        dq = data.qvel[arm]
        error[:3] = clamp_norm(data.site_xpos[self.tcp] - self.target_position,
                               self.gains.max_position_error)
        # The rotation from the target to the tool, as axis times angle.
        mujoco.mju_mat2Quat(quat, (data.site_xmat[self.tcp].reshape(3, 3)
                                   @ self.target_rotation.T).ravel())
        mujoco.mju_quat2Vel(error[3:], quat, 1.0)
        error[3:] = clamp_norm(error[3:], self.gains.max_rotation_error)
        task = jacobian.T @ (-self._stiffness * error - self._damping * (jacobian @ dq))
        # The posture torque less its part in the task: (I - J^T (J J^T)^-1 J) posture. J has
        # full rank away from singularities; the small diagonal keeps it bounded near them.
        posture = (self._null_stiffness * (self.nullspace_posture - data.qpos[arm])
                   - self._null_damping * dq)
        gram = jacobian @ jacobian.T + SINGULARITY_GUARD
        mujoco.mju_cholFactor(gram, 0.0)
        mujoco.mju_cholSolve(self._task_space, gram, jacobian @ posture)
        wanted = task + posture - jacobian.T @ self._task_space
        change = np.minimum(np.maximum(wanted - self.task_torque, -self._rate_step),
                            self._rate_step)
        self.task_torque += change
        return np.minimum(np.maximum(self.task_torque + data.qfrc_bias[arm], -TORQUE_LIMITS),
                          TORQUE_LIMITS)

    def step(self, now=None):
        """Advance one timestep; `now` (s, the commands' clock) defaults to simulated time."""
        model, data = self.model, self.data
        mujoco.mj_step1(model, data)
        self._update_target(data.time if now is None else now, model.opt.timestep)
        self.torque = self._control()
        data.ctrl[:7] = self.torque
        mujoco.mj_step2(model, data)

    # -- the sensor --------------------------------------------------------------------

    def wrench(self):
        """
        Return the F/T reading (N, N*m; sensor frame): the wrench the tool applies to the sensor.

        That is the tool's weight and inertia plus the contacts' push on the tool, moments about
        the sensor's origin, with the sensor model's bias and noise on top.
        """
        data, sensor = self.data, self.sensor
        # MuJoCo gives the force its parent body exerts on the tool: the sensor's is opposite.
        force = -data.sensordata[self._force_adr:self._force_adr + 3]
        torque = -data.sensordata[self._torque_adr:self._torque_adr + 3]
        reading = np.concatenate((force + sensor.force_bias, torque + sensor.torque_bias))
        if sensor.force_noise > 0.0:
            reading[:3] += self._rng.normal(0.0, sensor.force_noise, 3)
        if sensor.torque_noise > 0.0:
            reading[3:] += self._rng.normal(0.0, sensor.torque_noise, 3)
        return reading

    def sensor_rotation(self):
        """Return the sensor frame's rotation matrix (arm base frame)."""
        return self.data.site_xmat[self.ft_site].reshape(3, 3).copy()

    def table_deflection(self):
        """Return how far the table top is pushed down from its rest (m)."""
        return -float(self.data.qpos[self.table_spring]) + self.table_drop()

    def table_drop(self):
        """Return how far the table's rest was moved down by move_table (m)."""
        return -float(self.model.qpos_spring[self.table_spring])

    def move_table(self, drop):
        """Move the table top's rest `drop` m down (up if negative) from where it was built."""
        self.model.qpos_spring[self.table_spring] = -float(drop)

    def table_contact_force(self):
        """Return the table's force on the tool (N, arm base frame), from the contacts."""
        model, data = self.model, self.data
        total = np.zeros(3)
        wrench = np.zeros(6)
        for index in range(data.ncon):
            contact = data.contact[index]
            geoms = (contact.geom1, contact.geom2)
            if self.table_geom not in geoms:
                continue
            other = geoms[1] if geoms[0] == self.table_geom else geoms[0]
            if model.geom_bodyid[other] != self.tool_body:
                continue
            mujoco.mj_contactForce(model, data, index, wrench)
            # The contact frame's rows are its axes; the force acts on geom2, from geom1.
            force = contact.frame.reshape(3, 3).T @ wrench[:3]
            total += force if contact.geom2 == other else -force
        return total
