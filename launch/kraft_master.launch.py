# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Launch one or both Kraft Master drivers, each in its own namespace (right, left).

    ros2 launch kraft_master_driver kraft_master.launch.py arms:=both rsp:=true

Each driver loads config/<arm>_arm.yaml from the package's share directory. Frames get the
arm as prefix ('right/kraft_master_base', 'right/kraft_master_wrist'), so two arms share one
TF tree: wrenches sent to a driver must carry its prefixed frame_id. With rsp:=true a
robot_state_publisher per arm publishes the arm's URDF links on TF from its joint_states.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = 'kraft_master_driver'
ARM_SETS = {'right': ('right',), 'left': ('left',), 'both': ('right', 'left')}
BOOLEANS = ('true', 'false')


def frame_names(arm):
    """Return the driver's frame parameters for `arm`: its frames prefixed with the arm."""
    return {'base_frame': f'{arm}/kraft_master_base', 'wrist_frame': f'{arm}/kraft_master_wrist'}


def arm_nodes(arm, port, force_enabled, sim_operator, rate_command, rsp):
    """Return the driver of `arm` and, if `rsp`, its robot_state_publisher."""
    share = get_package_share_directory(PACKAGE)
    nodes = [Node(
        package=PACKAGE, executable='kraft_master_node', namespace=arm, output='screen',
        parameters=[
            os.path.join(share, 'config', f'{arm}_arm.yaml'),
            {'port': port, 'force_enabled_at_start': force_enabled,
             'sim_operator': sim_operator, 'rate_command_enabled': rate_command,
             **frame_names(arm)},
        ])]
    if rsp:
        with open(os.path.join(share, 'urdf', f'kraft_master_{arm}.urdf')) as urdf:
            description = urdf.read()
        nodes.append(Node(
            package='robot_state_publisher', executable='robot_state_publisher',
            namespace=arm, output='screen',
            parameters=[{'robot_description': description, 'frame_prefix': f'{arm}/'}]))
    return nodes


def _nodes(context):
    def value(name):
        return LaunchConfiguration(name).perform(context)

    nodes = []
    for arm in ARM_SETS[value('arms')]:
        nodes += arm_nodes(arm, value(f'{arm}_port'), value('force_enabled') == 'true',
                           value('sim_operator'), value('rate_command') == 'true',
                           value('rsp') == 'true')
    return nodes


def generate_launch_description():
    """Declare the arguments; the nodes are made once their values are known."""
    return LaunchDescription([
        DeclareLaunchArgument('arms', default_value='right', choices=list(ARM_SETS),
                              description='Which arms to run: right, left or both.'),
        DeclareLaunchArgument('right_port', default_value='/dev/ttyUSB0',
                              description='Serial port of the right arm ("sim": simulated).'),
        DeclareLaunchArgument('left_port', default_value='/dev/ttyUSB1',
                              description='Serial port of the left arm ("sim": simulated).'),
        DeclareLaunchArgument('rsp', default_value='false', choices=BOOLEANS,
                              description='Also run robot_state_publisher with the URDF.'),
        DeclareLaunchArgument('force_enabled', default_value='false', choices=BOOLEANS,
                              description='Force output enabled at start-up.'),
        DeclareLaunchArgument('rate_command', default_value='false', choices=BOOLEANS,
                              description='Publish rate_command (after a set_center call).'),
        DeclareLaunchArgument('sim_operator', default_value='hold',
                              choices=['hold', 'sweep', 'random_walk'],
                              description='Simulated operator hand, with port "sim".'),
        OpaqueFunction(function=_nodes),
    ])
