# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Launch one or both Kraft Master drivers, each in its own namespace (right, left).

    ros2 launch kraft_master_driver kraft_master.launch.py arms:=both rsp:=true \
        right_params_file:=/path/to/right_calibrated.yaml

Each driver loads its <arm>_params_file (default: config/<arm>_arm.yaml of the package's share
directory, the paper's nominal calibration). Every joint and frame name carries the arm as prefix
('right_shoulder_yaw', 'right_kraft_master_base'), in the driver's parameters and in
urdf/kraft_master_<arm>.urdf alike, so two arms share one TF tree: wrenches sent to a driver must
carry its prefixed frame_id. With rsp:=true a robot_state_publisher per arm publishes the arm's
URDF links on TF from its joint_states. With crtk:=true each driver also answers under CRTK's
names (measured_js, measured_cp, servo_cf; doc/ros-interface.md). Everything the launch needs
(parameter files, robot_state_publisher) is checked before any process starts.
"""
import os

from ament_index_python.packages import (
    get_package_prefix, get_package_share_directory, PackageNotFoundError)
from kraft_master_driver.core.calibration import ArmCalibration, CalibrationError
from kraft_master_driver.simulation.master.operators import OPERATORS
from kraft_master_driver.tools.urdf_model import driver_names, package_file_name
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = 'kraft_master_driver'
ARM_SETS = {'right': ('right',), 'left': ('left',), 'both': ('right', 'left')}
BOOLEANS = ('true', 'false')


class LaunchCheckError(RuntimeError):
    """What the launch needs is missing or wrong; raised before any process starts."""


def check_package(package, needed_by):
    """Raise LaunchCheckError unless the ROS package `package` is installed."""
    try:
        get_package_prefix(package)
    except PackageNotFoundError:
        raise LaunchCheckError(
            f'{needed_by} needs the ROS package {package}, which is not installed: run rosdep '
            f'install --from-paths src --ignore-src -y in your workspace (or apt install '
            f"ros-{os.environ.get('ROS_DISTRO', 'jazzy')}-{package.replace('_', '-')})"
        ) from None


def check_params_file(arm, path):
    """Raise LaunchCheckError unless `path` holds a valid calibration of `arm`."""
    try:
        calibration = ArmCalibration.from_yaml(path)
    except CalibrationError as error:
        raise LaunchCheckError(f'{arm}_params_file: {error}') from None
    if calibration.arm != arm:
        raise LaunchCheckError(
            f'{arm}_params_file: {path} calibrates the {calibration.arm} arm, not the {arm} arm')


def arm_nodes(arm, params_file, port, force_enabled, sim_operator, rate_command, rsp,
              crtk=False):
    """Return the driver of `arm` and, if `rsp`, its robot_state_publisher."""
    nodes = [Node(
        package=PACKAGE, executable='kraft_master_node', namespace=arm, output='screen',
        parameters=[
            params_file,
            {'port': port, 'force_enabled_at_start': force_enabled,
             'sim_operator': sim_operator, 'rate_command_enabled': rate_command,
             'crtk_names': crtk, **driver_names(arm)},
        ])]
    if rsp:
        share = get_package_share_directory(PACKAGE)
        with open(os.path.join(share, 'urdf', package_file_name(arm))) as urdf:
            description = urdf.read()
        nodes.append(Node(
            package='robot_state_publisher', executable='robot_state_publisher',
            namespace=arm, output='screen', parameters=[{'robot_description': description}]))
    return nodes


def _nodes(context):
    def value(name):
        return LaunchConfiguration(name).perform(context)

    arms, rsp = ARM_SETS[value('arms')], value('rsp') == 'true'
    if rsp:
        check_package('robot_state_publisher', 'rsp:=true')
    params_files = {arm: os.path.abspath(value(f'{arm}_params_file')) for arm in arms}
    for arm, path in params_files.items():
        check_params_file(arm, path)
    nodes = []
    for arm in arms:
        nodes += arm_nodes(arm, params_files[arm], value(f'{arm}_port'),
                           value('force_enabled') == 'true', value('sim_operator'),
                           value('rate_command') == 'true', rsp, value('crtk') == 'true')
    return nodes


def generate_launch_description():
    """Declare the arguments; the nodes are made once their values are known and checked."""
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
                              description='Parameter file of the right arm, such as one '
                                          'kraft_master_calibrate wrote.'),
        DeclareLaunchArgument('left_params_file',
                              default_value=os.path.join(config, 'left_arm.yaml'),
                              description='Parameter file of the left arm, such as one '
                                          'kraft_master_calibrate wrote.'),
        DeclareLaunchArgument('rsp', default_value='false', choices=BOOLEANS,
                              description='Also run robot_state_publisher with the URDF.'),
        DeclareLaunchArgument('force_enabled', default_value='false', choices=BOOLEANS,
                              description='Force output enabled at start-up.'),
        DeclareLaunchArgument('rate_command', default_value='false', choices=BOOLEANS,
                              description='Publish rate_command (after a set_center call).'),
        DeclareLaunchArgument('crtk', default_value='false', choices=BOOLEANS,
                              description='Also answer under CRTK names: measured_js, '
                                          'measured_cp, servo_cf.'),
        DeclareLaunchArgument('sim_operator', default_value='hold', choices=list(OPERATORS),
                              description='Simulated operator hand, with port "sim".'),
        OpaqueFunction(function=_nodes),
    ])
