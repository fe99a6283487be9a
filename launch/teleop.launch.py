# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Teleoperation: per arm the Kraft Master's driver, the bridge and a simulated arm behind it.

    ros2 launch kraft_master_driver teleop.launch.py arms:=both right_port:=sim left_port:=sim

For each arm (right, left or both), in the arm's namespace: the driver (kraft_master.launch.py,
with its arguments), the bridge kraft_master_teleop on the driver's topics and frames, and the
simulated arm (ARM below) on the bridge's arm-side topics (servo_cp or servo_cv in,
measured_cp and measured_cf out), in frames that carry the arm as prefix so that two pairs
share one TF tree. With enable:=true the bridge enables itself once the master's pose and the
arm's pose and force reading are fresh (the arm is simulated: nothing real moves); else call
/<arm>/enable. The driver's checks run before any process starts.
"""
import os

from ament_index_python.packages import get_package_share_directory
from kraft_master_driver.simulation.master.operators import OPERATORS
from kraft_master_driver.tools.urdf_model import driver_names
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription, OpaqueFunction
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = 'kraft_master_driver'
ARM = 'kraft_master_slave_sim'  # the simulated arm: any node speaking the arm-side topics
ARM_SETS = {'right': ('right',), 'left': ('left',), 'both': ('right', 'left')}
BOOLEANS = ('true', 'false')
MODES = ('pose', 'twist')
# Passed on to kraft_master.launch.py as they are.
DRIVER_ARGUMENTS = ('arms', 'right_port', 'left_port', 'right_params_file', 'left_params_file',
                    'rsp', 'force_enabled', 'sim_operator')


def arm_frames(arm):
    """Return the frames of the simulated arm of `arm`: its base, its wrist sensor."""
    return {'arm_frame': f'{arm}_sim_arm_base', 'ft_frame': f'{arm}_sim_arm_ft_sensor'}


def pair_nodes(arm, mode, enable):
    """Return the bridge and the simulated arm of `arm`, in its namespace."""
    frames = arm_frames(arm)
    return [
        # The simulated arm's wall holds it short of its command: no tracking fault for that.
        Node(package=PACKAGE, executable='kraft_master_teleop', namespace=arm, output='screen',
             parameters=[{'mode': mode, 'enable_at_start': enable, 'max_tracking_error': 1.0,
                          'master_frame': driver_names(arm)['base_frame'], **frames}]),
        Node(package=PACKAGE, executable=ARM, namespace=arm, output='screen',
             parameters=[{'mode': mode, **frames}]),
    ]


def _actions(context):
    def value(name):
        return LaunchConfiguration(name).perform(context)

    driver = os.path.join(get_package_share_directory(PACKAGE), 'launch', 'kraft_master.launch.py')
    actions = [IncludeLaunchDescription(
        PythonLaunchDescriptionSource(driver),
        launch_arguments={name: value(name) for name in DRIVER_ARGUMENTS}.items())]
    for arm in ARM_SETS[value('arms')]:
        actions += pair_nodes(arm, value('mode'), value('enable') == 'true')
    return actions


def generate_launch_description():
    """Declare the arguments; the actions are made once their values are known."""
    config = os.path.join(get_package_share_directory(PACKAGE), 'config')
    return LaunchDescription([
        DeclareLaunchArgument('arms', default_value='right', choices=list(ARM_SETS),
                              description='Which arms to run: right, left or both.'),
        DeclareLaunchArgument('right_port', default_value='/dev/ttyUSB0',
                              description='Serial port of the right arm ("sim": simulated).'),
        DeclareLaunchArgument('left_port', default_value='/dev/ttyUSB1',
                              description='Serial port of the left arm ("sim": simulated).'),
        DeclareLaunchArgument('right_params_file',
                              default_value=os.path.join(config, 'right_arm.yaml'),
                              description='Parameter file of the right arm.'),
        DeclareLaunchArgument('left_params_file',
                              default_value=os.path.join(config, 'left_arm.yaml'),
                              description='Parameter file of the left arm.'),
        DeclareLaunchArgument('mode', default_value='pose', choices=list(MODES),
                              description='The bridge sends servo_cp (pose) or servo_cv '
                                          '(twist), and the simulated arm takes it.'),
        DeclareLaunchArgument('enable', default_value='true', choices=BOOLEANS,
                              description='The bridge enables itself once its inputs are '
                                          'fresh; false: call the enable service.'),
        DeclareLaunchArgument('force_enabled', default_value='true', choices=BOOLEANS,
                              description="The driver's force output enabled at start-up."),
        DeclareLaunchArgument('sim_operator', default_value='hold', choices=list(OPERATORS),
                              description='Simulated operator hand, with port "sim".'),
        DeclareLaunchArgument('rsp', default_value='false', choices=BOOLEANS,
                              description='Also run robot_state_publisher with the URDF.'),
        OpaqueFunction(function=_actions),
    ])
