# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The launch files build their launch descriptions (where launch_ros is installed)."""
import importlib.util

from driver_harness import PACKAGE, REPO
import pytest

NOT_HERE = ('launch_ros cannot be installed on this machine: it is not on PyPI (it comes with '
            'a ROS 2 install; run these tests there)')
launch = pytest.importorskip('launch', reason=NOT_HERE)
launch_ros_actions = pytest.importorskip('launch_ros.actions', reason=NOT_HERE)

LAUNCH_DIR = REPO / 'launch'


def load(file_name):
    """Import a launch file as a module."""
    spec = importlib.util.spec_from_file_location(file_name.replace('.', '_'),
                                                  LAUNCH_DIR / file_name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def expand(description, **arguments):
    """Visit the top-level actions with `arguments` set; return what they produce."""
    context = launch.LaunchContext()
    context.launch_configurations.update(arguments)
    produced = []
    for entity in description.entities:
        produced += entity.visit(context) or []
    return produced


@pytest.fixture
def installed_share(install_prefix, monkeypatch):
    """Make the installed package's share directory findable, as a sourced workspace does."""
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(install_prefix))
    assert (install_prefix / 'share' / PACKAGE / 'launch' / 'kraft_master.launch.py').exists(), (
        'launch/ and urdf/ are not installed: check data_files in setup.py')


@pytest.mark.parametrize('file_name, arguments', [
    ('kraft_master.launch.py', {'arms', 'rsp', 'right_port', 'left_port', 'force_enabled'}),
    ('teleop_demo.launch.py', {'arm', 'mode', 'operator', 'rsp'}),
])
def test_launch_description_declares_its_arguments(file_name, arguments):
    description = load(file_name).generate_launch_description()
    assert isinstance(description, launch.LaunchDescription)
    declared = {a.name for a in description.entities
                if isinstance(a, launch.actions.DeclareLaunchArgument)}
    assert arguments <= declared


@pytest.mark.parametrize('arms, rsp, expected', [
    ('right', 'false', [(PACKAGE, 'kraft_master_node')]),
    ('both', 'true', [(PACKAGE, 'kraft_master_node'),
                      ('robot_state_publisher', 'robot_state_publisher')] * 2),
])
def test_kraft_master_launch_makes_one_driver_per_arm(installed_share, arms, rsp, expected):
    description = load('kraft_master.launch.py').generate_launch_description()
    nodes = expand(description, arms=arms, rsp=rsp)
    assert all(isinstance(node, launch_ros_actions.Node) for node in nodes)
    assert [(node.node_package, node.node_executable) for node in nodes] == expected


@pytest.mark.parametrize('mode, count', [('position', 2), ('rate', 3)])
def test_teleop_demo_includes_the_driver_and_starts_the_slave(installed_share, mode, count):
    actions = expand(load('teleop_demo.launch.py').generate_launch_description(), mode=mode)
    assert len(actions) == count
    assert isinstance(actions[0], launch.actions.IncludeLaunchDescription)
    assert (actions[1].node_package, actions[1].node_executable) == (
        PACKAGE, 'kraft_master_slave_sim')
