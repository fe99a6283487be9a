# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Teleoperation demo: a simulated Kraft Master, its driver, the bridge and a simulated arm.

    ros2 launch kraft_master_driver teleop_demo.launch.py mode:=pose sim_operator:=sweep
    ros2 launch kraft_master_driver teleop_demo.launch.py arm_model:=panda sim_operator:=push

teleop.launch.py with the built-in simulated hand controller (port sim) for each arm, moved by
a scripted operator hand, with force output on: the bridge (kraft_master_teleop) enables itself
once its inputs are fresh and maps the master's pose to the simulated arm (servo_cp in mode
pose, servo_cv in mode twist), the point mass meeting a stiff wall and a soft box or the Panda
its table; their contact forces, read by its wrist sensor, come back through the bridge as the
master's wrench. Everything runs in the arm's namespace with the arm's prefixed frame names;
the driver's checks run before any process starts. Its arguments are teleop.launch.py's, of the
same names and meanings.
"""
import os

from launch.launch_description_sources import load_python_launch_file_as_module

TELEOP = load_python_launch_file_as_module(
    os.path.join(os.path.dirname(__file__), 'teleop.launch.py'))
ARGUMENTS = ('arms', 'arm_model', 'mode', 'sim_operator', 'rsp')


def arguments():
    """Return the launch arguments by name: teleop.launch.py's, the operator sweeping."""
    declared = TELEOP.arguments(sim_operator='sweep')
    return {name: declared[name] for name in ARGUMENTS}


def _actions(value):
    arms = value('arms')
    return [TELEOP.DRIVER.scoped_include('teleop.launch.py', {
        'arms': arms, **{f'{arm}_port': 'sim' for arm in TELEOP.DRIVER.ARM_SETS[arms]},
        'force_enabled': 'true', 'enable': 'true', 'sim_operator': value('sim_operator'),
        'rsp': value('rsp'), 'mode': value('mode'), 'arm_model': value('arm_model')})]


def generate_launch_description():
    """Declare the arguments; the actions are made once their values are known."""
    return TELEOP.DRIVER.checked_launch('teleop_demo.launch.py', arguments(), _actions,
                                        TELEOP.REFUSED)
