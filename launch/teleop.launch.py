# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Teleoperation: per arm the Kraft Master's driver, the bridge and a simulated arm behind it.

    ros2 launch kraft_master_driver teleop.launch.py arms:=both right_port:=sim left_port:=sim
    ros2 launch kraft_master_driver teleop.launch.py right_port:=sim arm_model:=panda

For each arm (right, left or both), in the arm's namespace: the driver (kraft_master.launch.py,
given its arguments), the bridge kraft_master_teleop on the driver's topics and frames, and the
simulated arm that arm_model names (ARM_MODELS: the point mass, or the Franka Panda in MuJoCo
with the bridge settings of kraft_master_demo) on the bridge's arm-side topics (servo_cp or
servo_cv in, measured_cp and measured_cf out), in frames that carry the arm as prefix so that
two pairs share one TF tree. With enable:=true the bridge enables itself once the master's pose
and the arm's pose and force reading are fresh (the arm is simulated: nothing real moves); else
call /<arm>/enable. The driver's checks run before any process starts, and a node that fails
ends the launch with exit 1 (kraft_master.launch.py). crtk is not taken: the driver's CRTK
topics would be the simulated arm's, in the same namespace.
"""
import os

from kraft_master_driver.tools.urdf_model import driver_names
from launch.launch_description_sources import load_python_launch_file_as_module
from launch_ros.actions import Node

DRIVER = load_python_launch_file_as_module(
    os.path.join(os.path.dirname(__file__), 'kraft_master.launch.py'))
PACKAGE = DRIVER.PACKAGE
# The simulated arms: any node speaking the arm-side topics can stand here.
ARM_MODELS = {'point_mass': 'kraft_master_slave_sim', 'panda': 'kraft_master_arm_sim'}
MODES = ('pose', 'twist')
ARGUMENTS = ('arms', 'right_port', 'left_port', 'right_params_file', 'left_params_file',
             'arm_model', 'mode', 'enable', 'force_enabled', 'force_mode', 'contact_damping',
             'rate_command',
             'sim_operator', 'rsp')
REFUSED = {'crtk': "the driver's CRTK topics measured_cp and measured_js would be the simulated "
                   "arm's, which the bridge reads; kraft_master.launch.py takes it"}


def arguments(**defaults):
    """Return the launch arguments by name, with `defaults` ({name: value}) for theirs."""
    values = {'arm_model': 'point_mass', 'mode': 'pose', 'enable': 'true',
              'force_enabled': 'true', 'contact_damping': '', **defaults}
    declared = DRIVER.arguments(**{name: value for name, value in values.items()
                                   if name in DRIVER.ARGUMENTS})
    declared.update((argument.name, argument) for argument in (
        DRIVER.declare(values, 'arm_model', 'The simulated arm: a point mass meeting a wall and '
                       "a box, or the Franka Panda in MuJoCo over a table (with the demo's "
                       'bridge settings).', ARM_MODELS),
        DRIVER.declare(values, 'mode', 'The bridge sends servo_cp (pose) or servo_cv (twist), '
                       'and the simulated arm takes it.', MODES),
        DRIVER.declare(values, 'enable', 'The bridge enables itself once its inputs are fresh; '
                       'false: call the enable service.', DRIVER.BOOLEANS)))
    return {name: declared[name] for name in ARGUMENTS}


def arm_frames(arm):
    """Return the frames of the simulated arm of `arm`: its base, its wrist sensor."""
    return {'arm_frame': f'{arm}_sim_arm_base', 'ft_frame': f'{arm}_sim_arm_ft_sensor'}


def driver_settings(arm_model):
    """Return the driver's parameters that `arm_model` needs."""
    if arm_model == 'panda':
        from kraft_master_driver.tools.demo import MUJOCO_DRIVER
        return MUJOCO_DRIVER
    return {}


def bridge_settings(arm_model):
    """Return the bridge's parameters that `arm_model` needs."""
    if arm_model == 'panda':
        # MuJoCo and the demo's settings only where the Panda is asked for.
        from kraft_master_driver.tools.demo import MUJOCO_BRIDGE
        return MUJOCO_BRIDGE
    # The point mass's wall holds it short of its command: no tracking fault for that. A
    # simulated arm shares the machine with the whole session: a stale input is still a FAULT,
    # but after the demo's timeouts (2 s), as the Panda's, not a real arm's 0.1 s, which a
    # loaded machine overran in 6 of 8 launches.
    from kraft_master_driver.tools.demo import BRIDGE
    timeouts = {name: BRIDGE[name] for name in ('master_timeout', 'arm_timeout', 'ft_timeout')}
    return {**timeouts, 'max_tracking_error': 1.0}


def pair_nodes(arm, mode, enable, arm_model):
    """Return the bridge and the simulated arm of `arm`, in its namespace."""
    frames = arm_frames(arm)
    # The point mass takes the one command of its mode, the Panda either.
    arm_parameters = {'mode': mode, **frames} if arm_model == 'point_mass' else frames
    return [
        Node(package=PACKAGE, executable='kraft_master_teleop', namespace=arm, output='screen',
             on_exit=DRIVER.end_launch_if_failed,
             parameters=[{'mode': mode, 'enable_at_start': enable, **bridge_settings(arm_model),
                          'master_frame': driver_names(arm)['base_frame'], **frames}]),
        Node(package=PACKAGE, executable=ARM_MODELS[arm_model], namespace=arm, output='screen',
             on_exit=DRIVER.end_launch_if_failed, parameters=[arm_parameters]),
    ]


def _actions(value):
    model = driver_settings(value('arm_model'))

    def driver_value(name):
        # An argument left empty takes the arm model's setting, or the driver's default.
        if value(name) == '':
            return str(model.get(name, DRIVER.arguments()[name].default_value[0].text))
        return value(name)
    DRIVER.checked_parameters(driver_value)  # before any process of the pairs starts
    actions = [DRIVER.scoped_include('kraft_master.launch.py', {
        name: driver_value(name) for name in ARGUMENTS if name in DRIVER.ARGUMENTS})]
    for arm in DRIVER.ARM_SETS[value('arms')]:
        actions += pair_nodes(arm, value('mode'), value('enable') == 'true', value('arm_model'))
    return actions


def generate_launch_description():
    """Declare the arguments; the actions are made once their values are known."""
    return DRIVER.checked_launch('teleop.launch.py', arguments(), _actions, REFUSED)
