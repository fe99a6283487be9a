# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The launch files: arguments, the two-arm names, checks before any process (needs launch_ros)."""
import importlib.util
import os
import re
import shlex

from ament_index_python.packages import get_package_prefix, PackageNotFoundError
from harness import PACKAGE, REPO
from kraft_master_driver.nodes import driver_parameters, teleop_parameters
from kraft_master_driver.simulation.master.operators import OPERATORS
from kraft_master_driver.tools.urdf_model import driver_names
import pytest

NOT_HERE = ('launch_ros cannot be installed on this machine: it is not on PyPI (it comes with '
            'a ROS 2 install; run these tests there)')
launch = pytest.importorskip('launch', reason=NOT_HERE)
launch_ros_actions = pytest.importorskip('launch_ros.actions', reason=NOT_HERE)
launch_ros_utilities = pytest.importorskip('launch_ros.utilities', reason=NOT_HERE)

LAUNCH_DIR = REPO / 'launch'
DOC_PAGES = [REPO / 'README.md', *sorted((REPO / 'doc').glob('*.md'))]
PARAMETER_TABLES = {'kraft_master_node': driver_parameters.PARAMETERS,
                    'kraft_master_teleop': teleop_parameters.PARAMETERS}
SYSTEM_PREFIXES = os.environ.get('AMENT_PREFIX_PATH', '')


def load(file_name):
    """Import a launch file as a module."""
    spec = importlib.util.spec_from_file_location(file_name.replace('.', '_'),
                                                  LAUNCH_DIR / file_name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def expand(description, **arguments):
    """Visit the top-level actions with `arguments` set; return the context and what they make."""
    context = launch.LaunchContext()
    context.launch_configurations.update(arguments)
    produced = []
    for entity in description.entities:
        produced += entity.visit(context) or []
    return context, produced


def visit_in_launch_order(entity, context, started):
    """
    Visit `entity` depth-first, in the order the launch service does.

    Processes (nodes included) are appended to `started` where the launch service would start
    them, and not visited.
    """
    if isinstance(entity, launch.actions.ExecuteProcess):
        started.append(entity)
        return
    for child in entity.visit(context) or []:
        visit_in_launch_order(child, context, started)


def start_in_launch_order(description, started, **arguments):
    """Visit as the launch service does (visit_in_launch_order), with `arguments` set."""
    context = launch.LaunchContext()
    context.launch_configurations.update(arguments)
    visit_in_launch_order(description, context, started)
    return context


def launch_from_command_line(file_name, *argv):
    """
    Visit `file_name` as `ros2 launch kraft_master_driver <file_name> <argv>` does.

    Return the context and the processes the launch would start.
    """
    context = launch.LaunchContext(argv=list(argv))
    started = []
    visit_in_launch_order(launch.LaunchDescription([launch.actions.IncludeLaunchDescription(
        launch.launch_description_sources.PythonLaunchDescriptionSource(
            str(LAUNCH_DIR / file_name)),
        launch_arguments=[argument.split(':=', 1) for argument in argv])]), context, started)
    return context, started


def declared(description):
    """Return the description's launch arguments by name."""
    return {a.name: a for a in description.entities
            if isinstance(a, launch.actions.DeclareLaunchArgument)}


def text(context, value):
    """Return a launch value (a string or substitutions) as the launch makes it: a string."""
    return launch.utilities.perform_substitutions(
        context, launch.utilities.normalize_to_list_of_substitutions(value))


def node_parameters(context, node):
    """Return the parameter files and the merged name/value parameters a Node passes."""
    evaluated = launch_ros_utilities.evaluate_parameters(context, node._Node__parameters)
    files = [str(p) for p in evaluated if not isinstance(p, dict)]
    values = {k: v for p in evaluated if isinstance(p, dict) for k, v in p.items()}
    return files, values


@pytest.fixture
def installed_share(install_prefix, monkeypatch):
    """Make only the installed package findable, as a workspace sourced on its own does."""
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(install_prefix))
    assert (install_prefix / 'share' / PACKAGE / 'launch' / 'kraft_master.launch.py').exists(), (
        'launch/ and urdf/ are not installed: check data_files in setup.py')
    return install_prefix / 'share' / PACKAGE


@pytest.mark.parametrize('file_name, arguments, operator', [
    ('kraft_master.launch.py', {'arms', 'rsp', 'right_port', 'left_port', 'force_enabled',
                                'right_params_file', 'left_params_file', 'crtk',
                                'rate_command'},
     'sim_operator'),
    ('teleop_demo.launch.py', {'arms', 'arm_model', 'mode', 'rsp'}, 'sim_operator'),
    ('teleop.launch.py', {'arms', 'mode', 'enable', 'rsp', 'right_port', 'left_port',
                          'force_enabled', 'right_params_file', 'left_params_file',
                          'arm_model', 'rate_command'},
     'sim_operator'),
])
def test_launch_description_declares_its_arguments(installed_share, file_name, arguments,
                                                   operator):
    description = load(file_name).generate_launch_description()
    assert isinstance(description, launch.LaunchDescription)
    assert arguments | {operator} <= set(declared(description))
    assert list(declared(description)[operator].choices) == list(OPERATORS)


def readme_launch_commands():
    """Return (launch file, {argument: value}) of each `ros2 launch` line of README and doc/."""
    blocks = [block for page in DOC_PAGES for block in re.findall(
        r'```\n(.*?)```', page.read_text().replace('\\\n', ' '), re.DOTALL)]
    commands = []
    for block in blocks:
        for line in block.splitlines():
            if line.startswith(f'ros2 launch {PACKAGE} '):
                tokens = shlex.split(line, comments=True)
                commands.append((tokens[3], dict(t.split(':=', 1) for t in tokens[4:])))
    return commands


def test_readme_launch_commands_use_declared_arguments_and_choices(installed_share):
    commands = readme_launch_commands()
    assert {file_name for file_name, _ in commands} == {
        'kraft_master.launch.py', 'teleop_demo.launch.py', 'teleop.launch.py'}
    for file_name, arguments in commands:
        declarations = declared(load(file_name).generate_launch_description())
        for name, value in arguments.items():
            assert name in declarations, f'{file_name} has no argument {name}'
            assert not declarations[name].choices or value in declarations[name].choices


def test_each_driver_gets_its_params_file_and_the_arms_names(installed_share):
    description = load('kraft_master.launch.py').generate_launch_description()
    context, nodes = expand(description, arms='both', rsp='false', sim_operator='push')
    assert [(node.node_package, node.node_executable) for node in nodes] == [
        (PACKAGE, 'kraft_master_node')] * 2
    for arm, node in zip(('right', 'left'), nodes):
        files, values = node_parameters(context, node)
        assert files == [str(installed_share / 'config' / f'{arm}_arm.yaml')]
        assert {k: values[k] for k in driver_names(arm)} == driver_names(arm)
        assert values['sim_operator'] == 'push'
        assert values['crtk_names'] is False


def test_the_crtk_argument_gives_each_driver_the_crtk_names(installed_share):
    description = load('kraft_master.launch.py').generate_launch_description()
    context, nodes = expand(description, arms='both', crtk='true')
    assert [node_parameters(context, node)[1]['crtk_names'] for node in nodes] == [True, True]


def test_params_file_argument_replaces_the_shipped_one(installed_share, tmp_path):
    calibrated = tmp_path / 'right_calibrated.yaml'
    calibrated.write_text((installed_share / 'config' / 'right_arm.yaml').read_text())
    description = load('kraft_master.launch.py').generate_launch_description()
    context, (node,) = expand(description, right_params_file=str(calibrated))
    assert node_parameters(context, node)[0] == [str(calibrated)]


@pytest.mark.parametrize('file_name, message', [
    ('left_arm.yaml', 'calibrates the left arm, not the right arm'),
    ('does_not_exist.yaml', 'cannot read'),
])
def test_a_wrong_params_file_stops_the_launch_before_any_node(installed_share, file_name,
                                                              message):
    module = load('kraft_master.launch.py')
    with pytest.raises(module.LaunchCheckError, match=message):
        expand(module.generate_launch_description(), arms='both',
               right_params_file=str(installed_share / 'config' / file_name))


def test_rsp_without_robot_state_publisher_stops_the_launch_before_any_process(installed_share):
    with pytest.raises(PackageNotFoundError):
        get_package_prefix('robot_state_publisher')
    for file_name, arguments in (('kraft_master.launch.py', {'arms': 'both'}),
                                 ('teleop_demo.launch.py', {}),
                                 ('teleop.launch.py', {'arms': 'both'})):
        started = []
        with pytest.raises(Exception, match='needs the ROS package robot_state_publisher'):
            start_in_launch_order(load(file_name).generate_launch_description(), started,
                                  rsp='true', force_enabled='true', **arguments)
        assert started == [], file_name


def test_rsp_adds_a_robot_state_publisher_per_arm(installed_share, install_prefix,
                                                  monkeypatch):
    monkeypatch.setenv('AMENT_PREFIX_PATH', os.pathsep.join(
        filter(None, [str(install_prefix), SYSTEM_PREFIXES])))
    try:
        get_package_prefix('robot_state_publisher')
    except PackageNotFoundError:
        pytest.skip('robot_state_publisher is not installed here (C++, not on PyPI)')
    description = load('kraft_master.launch.py').generate_launch_description()
    _, nodes = expand(description, arms='both', rsp='true')
    assert [(node.node_package, node.node_executable) for node in nodes] == [
        (PACKAGE, 'kraft_master_node'), ('robot_state_publisher', 'robot_state_publisher')] * 2


def included_arguments(context, group):
    """Return the launch arguments the include of a scoped_include group passes, as strings."""
    assert isinstance(group, launch.actions.GroupAction)
    (include,) = [entity for entity in group.get_sub_entities()
                  if isinstance(entity, launch.actions.IncludeLaunchDescription)]
    return {text(context, name): text(context, value) for name, value in include.launch_arguments}


@pytest.mark.parametrize('arms, expected', [('right', ('right',)), ('left', ('left',)),
                                            ('both', ('right', 'left'))])
@pytest.mark.parametrize('mode', ['pose', 'twist'])
def test_teleop_runs_per_arm_its_driver_bridge_and_simulated_arm_in_its_frames(
        installed_share, arms, expected, mode):
    module = load('teleop.launch.py')
    context, actions = expand(module.generate_launch_description(), arms=arms, mode=mode,
                              right_port='sim', enable='false')
    include, *nodes = actions
    passed = included_arguments(context, include)
    assert passed['arms'] == arms and passed['right_port'] == 'sim'
    assert passed['force_enabled'] == 'true'
    assert [(n.node_package, n.node_executable) for n in nodes] == [
        (PACKAGE, 'kraft_master_teleop'), (PACKAGE, module.ARM_MODELS['point_mass'])
    ] * len(expected)
    for arm, bridge, simulated in zip(expected, nodes[::2], nodes[1::2]):
        bridge_values = node_parameters(context, bridge)[1]
        arm_values = node_parameters(context, simulated)[1]
        # Each pair in its arm's namespace, on the driver's base frame, the arm's frames agreed.
        for node in (bridge, simulated):
            assert text(context, node._Node__node_namespace) == arm
        assert bridge_values['master_frame'] == driver_names(arm)['base_frame']
        for name in ('arm_frame', 'ft_frame'):
            assert bridge_values[name] == arm_values[name]
            assert bridge_values[name].startswith(f'{arm}_')
        assert bridge_values['mode'] == arm_values['mode'] == mode
        assert bridge_values['enable_at_start'] is False


def test_teleop_demo_runs_teleop_for_one_simulated_arm_enabled_at_start(installed_share):
    context, actions = expand(load('teleop_demo.launch.py').generate_launch_description(),
                              arms='left', mode='twist')
    (include,) = actions
    assert included_arguments(context, include) == {
        'arms': 'left', 'left_port': 'sim', 'force_enabled': 'true', 'enable': 'true',
        'sim_operator': 'sweep', 'rsp': 'false', 'mode': 'twist', 'arm_model': 'point_mass'}


def test_the_three_files_share_one_vocabulary_that_show_args_lists(installed_share):
    files = ('kraft_master.launch.py', 'teleop.launch.py', 'teleop_demo.launch.py')
    modules = {file_name: load(file_name) for file_name in files}
    # What `ros2 launch ... --show-args` prints: the description's launch arguments.
    listed = {file_name: {a.name: a for a in module.generate_launch_description()
                          .get_launch_arguments()}
              for file_name, module in modules.items()}
    for file_name, arguments in listed.items():
        assert list(arguments) == list(modules[file_name].ARGUMENTS), file_name
        assert all(argument.description for argument in arguments.values()), file_name
    # A name means the same wherever it is taken: one description, one set of choices.
    for name in {name for arguments in listed.values() for name in arguments}:
        taken = [arguments[name] for arguments in listed.values() if name in arguments]
        assert len({(a.description, tuple(a.choices or ())) for a in taken}) == 1, name
    assert {'arms', 'arm_model', 'mode', 'sim_operator', 'rsp'} <= (
        set(listed['teleop.launch.py']) & set(listed['teleop_demo.launch.py']))


@pytest.mark.parametrize('file_name, argv, message', [
    ('teleop.launch.py', ('right_port:=sim', 'crtk:=true'),
     "takes no argument crtk (the driver's CRTK topics measured_cp and measured_js"),
    ('teleop_demo.launch.py', ('arm:=left', 'operator:=hold'),
     'teleop_demo.launch.py takes no argument arm, operator; it takes arms, arm_model'),
    ('teleop_demo.launch.py', ('right_port:=/dev/ttyUSB0',), 'takes no argument right_port'),
    ('kraft_master.launch.py', ('arms:=both', 'mode:=twist'), 'takes no argument mode'),
])
def test_an_argument_the_file_does_not_take_stops_the_launch_before_any_process(
        installed_share, file_name, argv, message):
    # Raised by the included file's own module: its LaunchCheckError, by name.
    with pytest.raises(RuntimeError, match=re.escape(message)) as raised:
        launch_from_command_line(file_name, *argv)
    assert raised.type.__name__ == 'LaunchCheckError'


@pytest.mark.parametrize('argv', [
    ('arms:=both', 'sim_operator:=hold'),
    # ros2 launch hands its --launch-prefix over as an argument: every file takes it.
    ('arms:=both', 'launch-prefix:=nice'),
])
def test_teleop_demo_takes_the_vocabularys_arms_and_sim_operator(installed_share, argv):
    context, started = launch_from_command_line('teleop_demo.launch.py', *argv)
    drivers = [node for node in started if node.node_executable == 'kraft_master_node']
    assert len(drivers) == 2
    for node in drivers:
        values = node_parameters(context, node)[1]
        assert values['port'] == 'sim'
        assert values['sim_operator'] == ('hold' if 'sim_operator:=hold' in argv else 'sweep')


def test_an_included_file_gets_only_its_arguments_not_its_includers(installed_share):
    # A parent that does not scope its include leaves its configuration to teleop.launch.py
    # (crtk here): the driver's launch file, which teleop.launch.py includes, does not see it.
    started = []
    context = start_in_launch_order(load('teleop.launch.py').generate_launch_description(),
                                    started, right_port='sim', crtk='true', mode='twist')
    (driver,) = [node for node in started if node.node_executable == 'kraft_master_node']
    assert node_parameters(context, driver)[1]['crtk_names'] is False


@pytest.mark.parametrize('mode', ['pose', 'twist'])
def test_the_panda_runs_behind_the_bridge_with_the_demos_settings_one_per_arm(
        installed_share, mode):
    from kraft_master_driver.tools.demo import MUJOCO_BRIDGE  # MuJoCo: only here
    module = load('teleop.launch.py')
    context, (_, *nodes) = expand(module.generate_launch_description(), arms='both',
                                  arm_model='panda', mode=mode)
    assert [(n.node_package, n.node_executable) for n in nodes] == [
        (PACKAGE, 'kraft_master_teleop'), (PACKAGE, 'kraft_master_arm_sim')] * 2
    frames = set()
    for arm, bridge, panda in zip(('right', 'left'), nodes[::2], nodes[1::2]):
        bridge_values = node_parameters(context, bridge)[1]
        panda_values = node_parameters(context, panda)[1]
        # Lists come out of the launch's evaluation as tuples.
        assert {k: bridge_values[k] for k in MUJOCO_BRIDGE} == {
            k: tuple(v) if isinstance(v, list) else v for k, v in MUJOCO_BRIDGE.items()}
        assert bridge_values['mode'] == mode
        # The Panda takes servo_cp and servo_cv alike: only its frames, the bridge's.
        assert panda_values == {k: bridge_values[k] for k in ('arm_frame', 'ft_frame')}
        for node in (bridge, panda):
            assert text(context, node._Node__node_namespace) == arm
        frames |= set(panda_values.values())
    # Two Pandas side by side: relative topics in their own namespaces, four frames.
    assert len(frames) == 4


def test_teleop_demo_runs_two_pandas_on_two_simulated_masters(installed_share):
    context, (include,) = expand(load('teleop_demo.launch.py').generate_launch_description(),
                                 arms='both', arm_model='panda')
    passed = included_arguments(context, include)
    assert {k: passed[k] for k in ('arms', 'right_port', 'left_port', 'arm_model')} == {
        'arms': 'both', 'right_port': 'sim', 'left_port': 'sim', 'arm_model': 'panda'}


@pytest.mark.parametrize('rate_command', ['false', 'true'])
def test_each_driver_publishes_rate_command_only_with_the_rate_command_argument(
        installed_share, rate_command):
    # teleop.launch.py hands the argument to the driver's launch file, which gives it to each
    # driver: without it, the driver advertises no rate_command.
    started = []
    context = start_in_launch_order(load('teleop.launch.py').generate_launch_description(),
                                    started, arms='both', right_port='sim', left_port='sim',
                                    rate_command=rate_command)
    drivers = [node for node in started if node.node_executable == 'kraft_master_node']
    assert len(drivers) == 2
    assert [node_parameters(context, node)[1]['rate_command_enabled'] for node in drivers] == [
        rate_command == 'true'] * 2


def doc_param_set_commands():
    """Return (node, parameter) of each `ros2 param set` command in README and doc/."""
    pages = '\n'.join(page.read_text().replace('\\\n', ' ') for page in DOC_PAGES)
    return re.findall(r'^ros2 param set (\S+) (\S+)|`ros2 param set (\S+) (\S+) [^`]*`', pages,
                      re.MULTILINE)


def test_the_docs_param_set_commands_name_a_launched_node_and_a_settable_parameter(
        installed_share):
    started = []
    context = start_in_launch_order(load('teleop.launch.py').generate_launch_description(),
                                    started, arms='both', right_port='sim', left_port='sim')
    launched = {f'/{text(context, node._Node__node_namespace)}/{node.node_executable}'
                for node in started}
    commands = [tuple(filter(None, found)) for found in doc_param_set_commands()]
    assert ('/right/kraft_master_teleop', 'scale') in commands
    for node, name in commands:
        namespace, executable = node.rsplit('/', 1)
        # A node in a namespace is one the launch file starts; one at the root, `ros2 run`'s.
        assert not namespace or node in launched, f'no launch file starts {node}'
        spec = PARAMETER_TABLES[executable].get(name)
        assert spec is not None and not spec.read_only, f'{node} {name} is not settable'


@pytest.mark.parametrize('file_name', ['kraft_master.launch.py', 'teleop.launch.py'])
@pytest.mark.parametrize('value, reason', [('-1', '-1.0 is outside 0..100'),
                                           ('abc', 'expected a number')])
def test_a_bad_contact_damping_stops_the_launch_before_any_process(installed_share, file_name,
                                                                   value, reason):
    with pytest.raises(RuntimeError) as raised:
        launch_from_command_line(file_name, 'right_port:=sim', f'contact_damping:={value}')
    assert raised.type.__name__ == 'LaunchCheckError'
    assert str(raised.value) == f'contact_damping:={value}: {reason}'


class Exited:
    """What the launch tells a process's on_exit: its name and exit code."""

    def __init__(self, process_name, returncode):
        """Keep both."""
        self.process_name, self.returncode = process_name, returncode


@pytest.mark.parametrize('file_name', ['kraft_master.launch.py', 'teleop.launch.py'])
def test_a_node_that_fails_ends_the_launch_with_exit_1(installed_share, file_name):
    # ros2 launch exits 1 on an exception in an event handler, and stops every process.
    context, started = launch_from_command_line(file_name, 'arms:=both', 'right_port:=sim',
                                                'left_port:=sim')
    assert started
    for process in started:
        on_exit = process._ExecuteProcess__on_exit
        assert on_exit.__name__ == 'end_launch_if_failed', process.node_executable
        assert on_exit(Exited('kraft_master_node-1', 0), context) is None
        with pytest.raises(RuntimeError, match=r'^kraft_master_node-1 exited with code 1; '
                                               'the launch stops$'):
            on_exit(Exited('kraft_master_node-1', 1), context)
