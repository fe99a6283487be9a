# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""What the teleoperation bridge is told (Settings), and its check: no ROS, SI units."""
from typing import NamedTuple

from kraft_master_driver.core.rotations import rotation_parameter
import numpy as np
import numpy.typing as npt

MODES = ('pose', 'twist')
ORIENTATIONS = ('follow', 'fixed', 'ignore')
# The force passivity's slave port books against the arm's commanded motion.
SLAVE_PORT_FORCES = ('contact', 'sent')
MAX_STEP = 0.05  # s: a longer gap between two master poses, or two wrenches, is taken as this

Array = npt.NDArray[np.float64]


class Settings(NamedTuple):
    """What the bridge is told: mapping, limits, timeouts and the force path (SI units)."""

    mode: str = 'pose'  # what the arm is sent: 'pose' (servo_cp) or 'twist' (servo_cv)
    scale: float = 1.0
    orientation: str = 'follow'
    base_rotation: tuple[float, ...] = (0.0, 0.0, 0.0)  # master base -> arm base, rpy or x y z w
    sensor_rotation: tuple[float, ...] = (0.0, 0.0, 0.0)  # sensor frame in the measured tool frame
    master_frame: str = 'kraft_master_base'
    arm_frame: str = 'base_link'
    ft_frame: str = 'ft_sensor'
    workspace_min: tuple[float, ...] = (-2.0, -2.0, -2.0)
    workspace_max: tuple[float, ...] = (2.0, 2.0, 2.0)
    max_linear_speed: float = 0.25  # m/s of the target
    max_angular_speed: float = 1.0  # rad/s of the target
    twist_gain: float = 10.0  # 1/s, twist mode: command = gain * (target - measured)
    master_timeout: float = 0.1
    arm_timeout: float = 0.1
    ft_timeout: float = 0.1
    max_tracking_error: float = 0.05  # m between the command and the measured arm
    max_tracking_angle: float = 0.5  # rad
    force_feedback: bool = True
    tool_mass: float = 0.0
    tool_com: tuple[float, ...] = (0.0, 0.0, 0.0)  # m, sensor frame
    gravity: tuple[float, ...] = (0.0, 0.0, -9.81)  # m/s^2, arm base frame
    force_scale: float = 1.0
    moment_scale: float = 1.0
    force_deadband: float = 0.0
    moment_deadband: float = 0.0
    force_cutoff_hz: float = 0.0  # 0: no low-pass
    force_resume_time: float = 0.1  # s over which the wrench comes in as following starts
    max_force: float = 10.0  # N, of the master's wrench
    max_moment: float = 1.0  # N*m
    arm_stiffness: float = 0.0  # N/m of the arm's impedance: the force sent is at most its pull
    max_input_force: float = 1000.0  # N: a larger F/T reading is refused
    max_input_moment: float = 100.0  # N*m
    max_input_position: float = 10.0  # m: a pose farther from its base is refused
    passivity: bool = False
    drift_gain: float = 2.0
    slave_port_force: str = 'contact'  # one of SLAVE_PORT_FORCES
    model_tolerance: float = 0.0  # N the contact force may exceed the contact model's; 0: any
    arm_hold_timeout: float = 0.1  # s: older arm inputs hold the arm (a FAULT comes later)


class Checked(NamedTuple):
    """The settings that are more than numbers, as arrays."""

    base_rotation: Array  # 3x3
    sensor_rotation: Array  # 3x3
    box: tuple[Array, Array]  # the workspace's lower and upper corner (m, 3 each)


def checked(settings: Settings) -> Checked:
    """Return the rotations and the workspace box of the settings; ValueError names a bad one."""
    for name, value, choices in (('mode', settings.mode, MODES),
                                 ('orientation', settings.orientation, ORIENTATIONS),
                                 ('slave_port_force', settings.slave_port_force,
                                  SLAVE_PORT_FORCES)):
        if value not in choices:
            raise ValueError(f'{name} must be one of {", ".join(choices)}, got {value!r}')
    base_rotation = rotation_parameter('base_rotation', settings.base_rotation)
    sensor_rotation = rotation_parameter('sensor_rotation', settings.sensor_rotation)
    box = (np.array(settings.workspace_min, dtype=float),
           np.array(settings.workspace_max, dtype=float))
    for name, corner in zip(('workspace_min', 'workspace_max'), box):
        if corner.shape != (3,):
            raise ValueError(f'{name}: expected 3 values, got {corner.size}')
    if not np.all(box[0] < box[1]):
        raise ValueError('workspace_min must be below workspace_max on every axis, got '
                         f'{list(settings.workspace_min)} and {list(settings.workspace_max)}')
    for name, vector in (('tool_com', settings.tool_com), ('gravity', settings.gravity)):
        values = np.array(vector, dtype=float)
        if values.shape != (3,) or not np.all(np.isfinite(values)):
            raise ValueError(f'{name} must be 3 finite numbers, got {list(vector)}')
    return Checked(base_rotation, sensor_rotation, box)
