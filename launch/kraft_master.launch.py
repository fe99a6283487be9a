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
(parameter files, robot_state_publisher, an argument that is a driver parameter's value, such
as contact_damping, checked as the driver would) is checked before any process starts. A node
that fails (exits non-zero) ends the launch, with exit 1.

The launch files share one vocabulary of arguments, each declared once: this file declares the
driver's, teleop.launch.py adds the bridge's and the arm's, and each file takes those of ARGUMENTS
(`ros2 launch ... --show-args` describes them). An argument given on the command line that a
file does not take stops the launch with one line (launch itself would ignore it), and a file
includes another with that file's arguments only (scoped_include).
"""
import os

from ament_index_python.packages import (
    get_package_prefix, get_package_share_directory, PackageNotFoundError)
from kraft_master_driver.core.calibration import ArmCalibration, CalibrationError
from kraft_master_driver.core.force_mode import ForceMode
from kraft_master_driver.nodes.driver_parameters import PARAMETERS
from kraft_master_driver.nodes.parameters import launch_argument, ParameterError
from kraft_master_driver.simulation.master.operators import OPERATORS
from kraft_master_driver.tools.urdf_model import driver_names, package_file_name
from launch import LaunchDescription
from launch.actions import (
    DeclareLaunchArgument, GroupAction, IncludeLaunchDescription, OpaqueFunction)
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = 'kraft_master_driver'
ARM_SETS = {'right': ('right',), 'left': ('left',), 'both': ('right', 'left')}
BOOLEANS = ('true', 'false')
FORCE_MODES = tuple(ForceMode)
ARGUMENTS = ('arms', 'right_port', 'left_port', 'right_params_file', 'left_params_file',
             'force_enabled', 'force_mode', 'contact_damping', 'rate_command', 'crtk',
             'sim_operator', 'rsp')
# ros2 launch's own options (--launch-prefix), which it hands over as launch arguments.
LAUNCH_OPTIONS = ('launch-prefix', 'launch-prefix-filter')
# The arguments that are the value of the driver's parameter of the same name.
PARAMETER_ARGUMENTS = ('contact_damping',)


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


def checked_parameters(value):
    """Return {name: value} of the PARAMETER_ARGUMENTS; LaunchCheckError naming a bad one."""
    try:
        return {name: launch_argument(PARAMETERS, name, value(name))
                for name in PARAMETER_ARGUMENTS}
    except ParameterError as error:
        raise LaunchCheckError(str(error)) from None


def end_launch_if_failed(event, _context):
    """
    End the launch with exit 1 if a node's process exited non-zero (every node's on_exit).

    A node that dies at start-up (a parameter it refuses) ends the launch rather than leave the
    others running without it; an exception here is what makes ros2 launch exit 1.
    """
    if event.returncode != 0:
        raise LaunchCheckError(f'{event.process_name} exited with code {event.returncode}; '
                               'the launch stops')


def check_given(context, file_name, names, refused):
    """
    Raise LaunchCheckError if the command line gave `file_name` an argument not in `names`.

    Only what the command line gave and reached this file's launch configurations counts: an
    included file sees only what its includer passes it (scoped_include). `refused`
    ({name: reason}) says why a name is not taken.
    """
    given = {argument.split(':=', 1)[0] for argument in context.argv}
    unknown = sorted(given & set(context.launch_configurations)
                     - set(names) - set(LAUNCH_OPTIONS))
    if unknown:
        reasons = ''.join(f' ({refused[name]})' for name in unknown if name in refused)
        raise LaunchCheckError(
            f"{file_name} takes no argument {', '.join(unknown)}{reasons}; it takes "
            f"{', '.join(names)}")


def checked_launch(file_name, declarations, actions, refused=None):
    """
    Return the launch description of `file_name`: its `declarations`, then its actions.

    `declarations`: {name: DeclareLaunchArgument}. The actions, `actions(value)` with
    value(name) the argument's value, are made once the arguments given are checked
    (check_given, `refused` its reasons).
    """
    def checked_actions(context):
        check_given(context, file_name, list(declarations), refused or {})
        return actions(lambda name: LaunchConfiguration(name).perform(context))

    return LaunchDescription([*declarations.values(), OpaqueFunction(function=checked_actions)])


def scoped_include(file_name, arguments):
    """
    Include the launch file `file_name` of this directory with `arguments` ({name: value}).

    It gets those and ros2 launch's own options, and nothing else of the includer's launch
    configuration; what it sets stays in it.
    """
    path = os.path.join(os.path.dirname(__file__), file_name)
    return GroupAction(
        [IncludeLaunchDescription(PythonLaunchDescriptionSource(path),
                                  launch_arguments=arguments.items())],
        scoped=True, forwarding=False,
        launch_configurations={name: LaunchConfiguration(name, default='')
                               for name in LAUNCH_OPTIONS})


def declare(defaults, name, description, choices=None):
    """Return the launch argument `name`, its default defaults[name], its choices as a list."""
    return DeclareLaunchArgument(name, default_value=defaults[name], description=description,
                                 choices=None if choices is None else list(choices))


def arguments(**defaults):
    """Return the driver's launch arguments by name, with `defaults` ({name: value}) for theirs."""
    config = os.path.join(get_package_share_directory(PACKAGE), 'config')
    values = {'arms': 'right', 'right_port': '/dev/ttyUSB0', 'left_port': '/dev/ttyUSB1',
              'right_params_file': os.path.join(config, 'right_arm.yaml'),
              'left_params_file': os.path.join(config, 'left_arm.yaml'),
              'force_enabled': 'false', 'force_mode': 'auto', 'contact_damping': '0.0',
              'rate_command': 'false',
              'crtk': 'false',
              'sim_operator': 'hold', 'rsp': 'false', **defaults}
    return {argument.name: argument for argument in (
        declare(values, 'arms', 'Which arms to run: right, left or both.', ARM_SETS),
        declare(values, 'right_port', 'Serial port of the right arm ("sim": simulated).'),
        declare(values, 'left_port', 'Serial port of the left arm ("sim": simulated).'),
        declare(values, 'right_params_file', 'Parameter file of the right arm, such as one '
                                             'kraft_master_calibrate wrote.'),
        declare(values, 'left_params_file', 'Parameter file of the left arm, such as one '
                                            'kraft_master_calibrate wrote.'),
        declare(values, 'force_enabled', "The driver's force output enabled at start-up.",
                BOOLEANS),
        declare(values, 'force_mode', "The driver's force_mode: direct (the arm's wrench), "
                                      "model (the arm's contact model, rendered locally) or "
                                      'auto (chosen by the measured round trip).', FORCE_MODES),
        declare(values, 'contact_damping', "The driver's contact_damping (s/m): damping of the "
                                           'wrist per newton of the force reflected '
                                           "(teleop.launch.py: empty takes the arm model's)."),
        declare(values, 'rate_command', 'Publish rate_command (after a set_center call).',
                BOOLEANS),
        declare(values, 'crtk', 'Also answer under CRTK names: measured_js, measured_cp, '
                                'servo_cf.', BOOLEANS),
        declare(values, 'sim_operator', 'What the simulated operator hand does, with port '
                                        '"sim".', OPERATORS),
        declare(values, 'rsp', 'Also run robot_state_publisher with the URDF.', BOOLEANS),
    )}


def arm_nodes(arm, params_file, port, force_enabled, sim_operator, rate_command, rsp,
              crtk=False, contact_damping=0.0, force_mode='auto'):
    """Return the driver of `arm` and, if `rsp`, its robot_state_publisher."""
    nodes = [Node(
        package=PACKAGE, executable='kraft_master_node', namespace=arm, output='screen',
        on_exit=end_launch_if_failed, parameters=[
            params_file,
            {'port': port, 'force_enabled_at_start': force_enabled,
             'contact_damping': contact_damping, 'force_mode': force_mode,
             'sim_operator': sim_operator, 'rate_command_enabled': rate_command,
             'crtk_names': crtk, **driver_names(arm)},
        ])]
    if rsp:
        share = get_package_share_directory(PACKAGE)
        with open(os.path.join(share, 'urdf', package_file_name(arm))) as urdf:
            description = urdf.read()
        nodes.append(Node(
            package='robot_state_publisher', executable='robot_state_publisher',
            namespace=arm, output='screen', on_exit=end_launch_if_failed,
            parameters=[{'robot_description': description}]))
    return nodes


def _nodes(value):
    parameters = checked_parameters(value)
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
                           value('rate_command') == 'true', rsp, value('crtk') == 'true',
                           parameters['contact_damping'], value('force_mode'))
    return nodes


def generate_launch_description():
    """Declare the arguments; the nodes are made once their values are known and checked."""
    return checked_launch('kraft_master.launch.py', arguments(), _nodes)
