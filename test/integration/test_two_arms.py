# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""One two-arm convention: the docs' recipe, the URDFs, the driver, the RViz config agree."""
import contextlib
import io
import re
import shlex

from harness import PACKAGE, REPO
from harness.driver import DriverProcess, next_domain_id, RosClient
from kraft_master_driver.core import kinematics
from kraft_master_driver.nodes.driver_parameters import PARAMETERS
from kraft_master_driver.simulation.master.operators import OPERATORS
from kraft_master_driver.tools.urdf_model import driver_names, main, package_urdf
import numpy as np
import pytest
import rclpy
import yaml
import yourdfpy

README = (REPO / 'doc' / 'getting-started.md').read_text()
RVIZ = REPO / 'rviz' / 'kraft_master.rviz'
WRENCH = (3.0, -2.0, 4.0, 0.05, -0.1, 0.08)


def readme_recipe():
    """Return the two-arm recipe of doc/getting-started.md: {namespace: (driver, URDF args)}."""
    blocks = re.findall(r'```\n(.*?)```', README, re.DOTALL)
    (block,) = [b for b in blocks if 'kraft_master_urdf --arm left' in b]
    recipe = {}
    for line in block.replace('\\\n', ' ').splitlines():
        tokens = shlex.split(line)
        namespace = tokens[tokens.index('-r') + 1].removeprefix('__ns:=/')
        driver, publisher = recipe.get(namespace, (None, None))
        if tokens[:4] == ['ros2', 'run', PACKAGE, 'kraft_master_node']:
            driver = tokens
        else:
            assert tokens[:4] == ['ros2', 'run', 'robot_state_publisher',
                                  'robot_state_publisher'], line
            publisher = tokens
        recipe[namespace] = driver, publisher
    return recipe


def urdf_arguments(publisher):
    """Return the kraft_master_urdf arguments of a robot_state_publisher command line."""
    (description,) = [t for t in publisher if t.startswith('robot_description:=')]
    command = re.fullmatch(r'robot_description:=\$\((.*)\)', description).group(1)
    words = command.split()
    assert words[:4] == ['ros2', 'run', PACKAGE, 'kraft_master_urdf'], command
    return words[4:]


def driver_parameters(tokens):
    """Return the `-p name:=value` parameters of a driver command line."""
    pairs = [tokens[i + 1].split(':=', 1) for i, t in enumerate(tokens) if t == '-p']
    return dict(pairs)


def params_file(tokens):
    """Return the repository's copy of the parameter file a driver command line names."""
    path = tokens[tokens.index('--params-file') + 1]
    return REPO / path.removeprefix(f'src/{PACKAGE}/')


def urdf_from_tool(arguments):
    """Return (text, yourdfpy model) of what `kraft_master_urdf arguments` prints."""
    output = io.StringIO()
    with contextlib.redirect_stdout(output):
        assert main(arguments) == 0
    return output.getvalue(), yourdfpy.URDF.load(io.StringIO(output.getvalue()))


RECIPE = readme_recipe()


def test_the_recipe_runs_each_arm_with_its_driver_and_its_robot_state_publisher():
    assert set(RECIPE) == set(kinematics.ARMS)
    for arm, (driver, publisher) in RECIPE.items():
        assert driver and urdf_arguments(publisher) == ['--arm', arm], arm
        assert yaml.safe_load(params_file(driver).read_text())['/**']['ros__parameters'][
            'arm'] == arm


@pytest.mark.parametrize('arm', kinematics.ARMS)
def test_recipe_driver_names_are_the_urdf_names_and_the_launch_files(arm):
    driver, publisher = RECIPE[arm]
    names = driver_parameters(driver)
    assert {key: names[key] for key in driver_names(arm)} == driver_names(arm)
    text, robot = urdf_from_tool(urdf_arguments(publisher))
    assert text == package_urdf(arm) == (REPO / 'urdf' / f'kraft_master_{arm}.urdf').read_text()
    assert robot.actuated_joint_names == [
        names['joint_prefix'] + name for name in kinematics.JOINT_NAMES]
    assert robot.base_link == names['base_frame']
    assert names['wrist_frame'] in robot.link_map


def test_two_recipe_drivers_publish_the_urdf_names_and_take_wrenches_in_its_frames(
        install_prefix):
    domain_id = next_domain_id()
    drivers, clients = [], []
    try:
        for arm, (tokens, _) in RECIPE.items():
            parameters = {**driver_parameters(tokens), 'port': 'sim',
                          'force_enabled_at_start': 'true'}
            drivers.append(DriverProcess(install_prefix, domain_id, parameters.items(),
                                         namespace=f'/{arm}', params_file=params_file(tokens)))
            clients.append(RosClient(domain_id, namespace=f'/{arm}'))
        for arm, client, driver in zip(RECIPE, clients, drivers):
            _, robot = urdf_from_tool(urdf_arguments(RECIPE[arm][1]))
            try:
                client.wait_connected()
            except AssertionError:
                raise AssertionError(f'{arm} driver did not connect:\n'
                                     + driver.interrupt()[1])
            client.wait(lambda: client.poses)
            assert list(client.joint_states[-1].name) == robot.actuated_joint_names
            assert client.poses[-1].header.frame_id == robot.base_link
            wrist = driver_parameters(RECIPE[arm][0])['wrist_frame']
            assert wrist in robot.link_map
            client.stream_wrench_until(WRENCH, wrist, lambda: any(
                client.joint_states[-1].effort), timeout=60.0)
    finally:
        for client in clients:
            client.close()
        for driver in drivers:
            driver.kill()


@pytest.mark.parametrize('arm', kinematics.ARMS)
def test_recipe_robot_description_survives_rcl_parsing_the_command_line(arm):
    """The URDF comes through rcl, which reads `-p name:=value` as YAML, as the same model."""
    publisher = RECIPE[arm][1]
    text, robot = urdf_from_tool(urdf_arguments(publisher))
    arguments = [t if not t.startswith('robot_description:=') else 'robot_description:=' + text
                 for t in publisher[publisher.index('--ros-args'):]]
    context = rclpy.Context()
    rclpy.init(args=['robot_state_publisher', *arguments], context=context,
               domain_id=next_domain_id())
    try:
        node = rclpy.create_node('robot_state_publisher', context=context)
        assert node.get_namespace() == f'/{arm}'
        value = node.declare_parameter('robot_description', '').value
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    received = yourdfpy.URDF.load(io.StringIO(value))
    assert received.actuated_joint_names == robot.actuated_joint_names
    assert set(received.link_map) == set(robot.link_map)
    theta = np.radians([10.0, 60.0, -90.0, 20.0, 15.0, -30.0])
    for model in (robot, received):
        model.update_cfg(dict(zip(model.actuated_joint_names, theta)))
    names = driver_names(arm)
    np.testing.assert_allclose(
        received.get_transform(names['wrist_frame'], names['base_frame']),
        robot.get_transform(names['wrist_frame'], names['base_frame']), atol=1e-12)


def test_rviz_config_shows_the_right_arm_by_the_conventions_names(install_prefix):
    installed = install_prefix / 'share' / PACKAGE / 'rviz' / RVIZ.name
    assert installed.read_text() == RVIZ.read_text(), 'setup.py does not install rviz/'
    config = yaml.safe_load(RVIZ.read_text())['Visualization Manager']
    robot = yourdfpy.URDF.load(io.StringIO(package_urdf('right')))
    names = driver_names('right')
    assert config['Global Options']['Fixed Frame'] == names['base_frame'] == robot.base_link
    displays = {display['Class']: display for display in config['Displays']}
    model = displays['rviz_default_plugins/RobotModel']
    # robot_state_publisher in the namespace 'right' publishes robot_description there.
    assert model['Description Source'] == 'Topic'
    assert model['Description Topic']['Value'] == '/right/robot_description'
    assert model['Description Topic']['Durability Policy'] == 'Transient Local'
    assert model['TF Prefix'] == ''
    frames = set(displays['rviz_default_plugins/TF']['Frames']) - {'All Enabled'}
    assert frames and frames <= set(robot.link_map)
    assert names['wrist_frame'] in frames
    assert displays['rviz_default_plugins/Pose']['Topic']['Value'] == '/right/pose'


def test_the_nodes_simulated_operators_are_the_simulators():
    assert PARAMETERS['sim_operator'].choices == OPERATORS
