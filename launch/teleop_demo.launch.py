# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Teleoperation demo: a simulated Kraft Master, its driver, the bridge and a simulated arm.

    ros2 launch kraft_master_driver teleop_demo.launch.py mode:=pose operator:=sweep

teleop.launch.py for one arm with the built-in simulated hand controller (port sim), moved by a
scripted operator hand, with force output on: the bridge (kraft_master_teleop) enables itself
once its inputs are fresh and maps the master's pose to the simulated arm (servo_cp in mode
pose, servo_cv in mode twist), which meets a stiff wall and a soft box; their contact forces,
read by its wrist sensor, come back through the bridge as the master's wrench. Everything runs
in the arm's namespace with the arm's prefixed frame names; the driver's checks run before any
process starts.
"""
import os

from ament_index_python.packages import get_package_share_directory
from kraft_master_driver.core.kinematics import ARMS
from kraft_master_driver.simulation.master.operators import OPERATORS
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription, OpaqueFunction
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration

PACKAGE = 'kraft_master_driver'


def _actions(context):
    def value(name):
        return LaunchConfiguration(name).perform(context)

    arm = value('arm')
    teleop = os.path.join(get_package_share_directory(PACKAGE), 'launch', 'teleop.launch.py')
    return [IncludeLaunchDescription(
        PythonLaunchDescriptionSource(teleop),
        launch_arguments={
            'arms': arm, f'{arm}_port': 'sim', 'force_enabled': 'true', 'enable': 'true',
            'sim_operator': value('operator'), 'rsp': value('rsp'), 'mode': value('mode'),
        }.items())]


def generate_launch_description():
    """Declare the arguments; the actions are made once their values are known."""
    return LaunchDescription([
        DeclareLaunchArgument('arm', default_value='right', choices=list(ARMS),
                              description='Which arm to simulate.'),
        DeclareLaunchArgument('mode', default_value='pose', choices=['pose', 'twist'],
                              description='The bridge sends the arm servo_cp (pose) or '
                                          'servo_cv (twist).'),
        DeclareLaunchArgument('operator', default_value='sweep', choices=list(OPERATORS),
                              description='What the simulated operator hand does.'),
        DeclareLaunchArgument('rsp', default_value='false', choices=['true', 'false'],
                              description='Also run robot_state_publisher with the URDF.'),
        OpaqueFunction(function=_actions),
    ])
