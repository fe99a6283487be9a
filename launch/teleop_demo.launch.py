# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Teleoperation demo: a simulated Kraft Master, its driver and a simulated slave arm.

    ros2 launch kraft_master_driver teleop_demo.launch.py mode:=position operator:=sweep

The driver runs the built-in simulated hand controller (port sim), moved by a scripted operator
hand, with force output on. The slave (kraft_master_slave_sim) follows the master's pose
(mode position) or its rate command (mode rate; the driver's centre is then set 3 s after
start) in an environment with a stiff wall and a soft box, and its contact forces come back as
the master's wrench. Everything runs in the arm's namespace with the arm's prefixed frame names,
as kraft_master.launch.py does; its checks run before any process starts.
"""
import os

from ament_index_python.packages import get_package_share_directory
from kraft_master_driver.core.kinematics import ARMS
from kraft_master_driver.simulation.operators import OPERATORS
from kraft_master_driver.tools.urdf_model import driver_names
from launch import LaunchDescription
from launch.actions import (
    DeclareLaunchArgument, ExecuteProcess, IncludeLaunchDescription, OpaqueFunction, TimerAction)
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = 'kraft_master_driver'
CENTRE_DELAY = 3.0  # s after start, rate mode: the driver's set_center call


def _actions(context):
    def value(name):
        return LaunchConfiguration(name).perform(context)

    arm, mode = value('arm'), value('mode')
    driver = os.path.join(get_package_share_directory(PACKAGE), 'launch', 'kraft_master.launch.py')
    actions = [
        IncludeLaunchDescription(
            PythonLaunchDescriptionSource(driver),
            launch_arguments={
                'arms': arm, f'{arm}_port': 'sim', 'force_enabled': 'true',
                'sim_operator': value('operator'), 'rsp': value('rsp'),
                'rate_command': 'true' if mode == 'rate' else 'false',
            }.items()),
        Node(package=PACKAGE, executable='kraft_master_slave_sim', namespace=arm,
             output='screen',
             parameters=[{'mode': mode, 'arm': arm,
                          'base_frame': driver_names(arm)['base_frame']}]),
    ]
    if mode == 'rate':
        actions.append(TimerAction(period=CENTRE_DELAY, actions=[ExecuteProcess(
            cmd=['ros2', 'service', 'call', f'/{arm}/set_center', 'std_srvs/srv/Trigger'],
            output='screen')]))
    return actions


def generate_launch_description():
    """Declare the arguments; the actions are made once their values are known."""
    return LaunchDescription([
        DeclareLaunchArgument('arm', default_value='right', choices=list(ARMS),
                              description='Which arm to simulate.'),
        DeclareLaunchArgument('mode', default_value='position', choices=['position', 'rate'],
                              description='Slave follows the pose (position) or rate_command.'),
        DeclareLaunchArgument('operator', default_value='sweep', choices=list(OPERATORS),
                              description='What the simulated operator hand does.'),
        DeclareLaunchArgument('rsp', default_value='false', choices=['true', 'false'],
                              description='Also run robot_state_publisher with the URDF.'),
        OpaqueFunction(function=_actions),
    ])
