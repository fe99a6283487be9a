# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Tests of the parameter machinery: specs, types, ranges, choices, misspelt names, params files.

Nodes are real rclpy nodes in a context of this process, on a DDS domain of their own.
"""
import importlib
import itertools

from kraft_master_driver.nodes.parameters import (
    check_value, coerce_integers, declare_parameters, descriptor, launch_argument,
    ParameterError, read_params_file, reject_unknown, run_time_changes, Spec, usage)
import pytest
from rcl_interfaces.msg import ParameterType
import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter

TABLE = {
    'arm': Spec('right', 'Which unit.', choices=('right', 'left')),
    'baud': Spec(1_000_000, 'Baud rate (bit/s).', low=1200, high=12_000_000),
    'rate_hz': Spec(1000.0, 'Loop rate (Hz).', read_only=False, low=1.0, high=5000.0),
    'low_latency': Spec(False, 'Kernel low-latency mode.'),
    'port': Spec('/dev/ttyUSB0', 'Serial device path or pyserial URL of the hand controller; '
                 '"sim" starts a simulated one on a pseudo-terminal of this process.'),
    'lengths': Spec([0.1, 0.2, 0.3, 0.4], 'Link lengths (m).', read_only=False, low=0.001,
                    high=2.0, length=4),
    'limits': Spec([100, 200], 'Limits (counts).', low=1, high=32767, length=2),
    'frame_prefix': Spec('', 'Prefix of the frames.'),
    'rotation': Spec([0.0, 0.0, 0.0], 'Roll, pitch, yaw or x, y, z, w.', read_only=False,
                     length=(3, 4)),
    'corner': Spec([2.0, 2.0, 2.0], 'Corner of a box (m).', read_only=False, length=3),
}
# Every node's parameters; of their list parameters, these alone take any number of values.
NODE_TABLES = ('driver_parameters', 'teleop_parameters', 'arm_sim', 'slave_sim', 'link_emulator',
               'zenoh_link')
ANY_LENGTH = {'to_slave.topics', 'to_master.topics'}
_node_numbers = itertools.count()


@pytest.fixture(scope='module')
def context():
    """Yield a ROS context of this process, on a domain no other test uses."""
    context = rclpy.Context()
    rclpy.init(context=context, args=[], domain_id=231)
    yield context
    rclpy.try_shutdown(context=context)


@pytest.fixture
def make_node(context):
    """Return node(**overrides): a node given these parameters, as on a command line."""
    nodes = []

    def node(**overrides):
        nodes.append(Node(
            f'parameters_test_{next(_node_numbers)}', context=context,
            parameter_overrides=[Parameter(name, value=value)
                                 for name, value in overrides.items()],
            use_global_arguments=False, start_parameter_services=False, enable_rosout=False))
        return nodes[-1]
    yield node
    for created in nodes:
        created.destroy_node()


def refusal(call, *args):
    """Return the message of the ParameterError call(*args) raises; it is one line."""
    with pytest.raises(ParameterError) as raised:
        call(*args)
    message = str(raised.value)
    assert '\n' not in message
    return message


# -- values ------------------------------------------------------------------------------------


def test_a_value_in_range_is_returned():
    assert check_value(TABLE, 'rate_hz', 1.0) == 1.0
    assert check_value(TABLE, 'rate_hz', 5000.0) == 5000.0
    assert check_value(TABLE, 'baud', 1200) == 1200
    assert check_value(TABLE, 'port', 'socket://host:9100') == 'socket://host:9100'


@pytest.mark.parametrize('name, value, message', [
    ('rate_hz', 0.5, 'parameter rate_hz: 0.5 is outside 1..5000'),
    ('rate_hz', 5000.5, 'parameter rate_hz: 5000.5 is outside 1..5000'),
    ('rate_hz', float('nan'), 'parameter rate_hz: nan is outside 1..5000'),
    ('rate_hz', float('inf'), 'parameter rate_hz: inf is outside 1..5000'),
    ('baud', 1199, 'parameter baud: 1199 is outside 1200..12000000'),
    ('arm', 'middle', "parameter arm: 'middle' is not one of right, left"),
    ('lengths', [0.1, 0.2], 'parameter lengths: expected 4 values, got 2'),
    ('lengths', [0.1, 0.2, 3.0, 0.4], 'parameter lengths: 3.0 is outside 0.001..2'),
    ('limits', [0, 200], 'parameter limits: 0 is outside 1..32767'),
    ('port', None, 'parameter port: no value (an empty list has no type)'),
    ('corner', [5.0, 5.0], 'parameter corner: expected 3 values, got 2'),
    ('corner', [5.0], 'parameter corner: expected 3 values, got 1'),
    ('rotation', [0.0, 1.0], 'parameter rotation: expected 3 or 4 values, got 2'),
    ('rotation', [0.0] * 5, 'parameter rotation: expected 3 or 4 values, got 5'),
])
def test_a_value_out_of_its_spec_is_refused_in_one_line_naming_it(name, value, message):
    assert refusal(check_value, TABLE, name, value) == message


def test_a_list_value_comes_back_as_a_list():
    assert check_value(TABLE, 'lengths', (0.1, 0.2, 0.3, 0.4)) == [0.1, 0.2, 0.3, 0.4]
    assert check_value(TABLE, 'rotation', [0.0, 0.0, 0.0, 1.0]) == [0.0, 0.0, 0.0, 1.0]
    assert check_value(TABLE, 'corner', [-1.0, 0.0, 1e9]) == [-1.0, 0.0, 1e9]


@pytest.mark.parametrize('module', NODE_TABLES)
def test_every_list_parameter_of_every_node_has_its_length_checked(module):
    table = importlib.import_module(f'kraft_master_driver.nodes.{module}').PARAMETERS
    for name, spec in table.items():
        if isinstance(spec.default, list) and name not in ANY_LENGTH:
            assert spec.length, f'{module}: {name} has no length'
            assert check_value(table, name, spec.default) == spec.default
            short = spec.default[:-1]
            assert refusal(check_value, table, name, short).startswith(
                f'parameter {name}: expected '), name


def test_a_run_time_set_is_checked_as_at_start_up_and_refused_if_read_only():
    given = [Parameter('rate_hz', value=500.0), Parameter('lengths', value=[0.1, 0.2, 0.3, 0.4]),
             Parameter('use_sim_time', value=True)]
    assert run_time_changes(TABLE, given) == {'rate_hz': 500.0, 'lengths': [0.1, 0.2, 0.3, 0.4]}
    assert refusal(run_time_changes, TABLE, [Parameter('rate_hz', value=0.5)]) == (
        'parameter rate_hz: 0.5 is outside 1..5000')
    assert refusal(run_time_changes, TABLE, [Parameter('rate_hz', value=500.0),
                                             Parameter('baud', value=9600)]) == (
        'parameter baud is read-only')
    assert refusal(run_time_changes, TABLE, [Parameter('corner', value=[5.0, 5.0])]) == (
        'parameter corner: expected 3 values, got 2')


def test_integers_become_doubles_only_for_floating_point_parameters():
    given = [Parameter('rate_hz', value=500), Parameter('lengths', value=[1, 1, 1, 1]),
             Parameter('baud', value=9600), Parameter('unknown', value=3),
             Parameter('rate_hz', value=500.5)]
    coerced = coerce_integers(TABLE, given)
    assert [(p.name, p.type_, p.value) for p in coerced] == [
        ('rate_hz', Parameter.Type.DOUBLE, 500.0),
        ('lengths', Parameter.Type.DOUBLE_ARRAY, [1.0, 1.0, 1.0, 1.0]),
        ('baud', Parameter.Type.INTEGER, 9600),
        ('unknown', Parameter.Type.INTEGER, 3),
        ('rate_hz', Parameter.Type.DOUBLE, 500.5)]
    assert all(type(x) is float for x in coerced[1].value)


def test_the_descriptor_carries_the_range_the_choices_and_read_only():
    baud = descriptor('baud', TABLE['baud'])
    assert (baud.integer_range[0].from_value, baud.integer_range[0].to_value) == (1200, 12000000)
    assert baud.read_only and not baud.floating_point_range
    rate = descriptor('rate_hz', TABLE['rate_hz'])
    assert (rate.floating_point_range[0].from_value,
            rate.floating_point_range[0].to_value) == (1.0, 5000.0)
    assert not rate.read_only and rate.description == 'Loop rate (Hz).'
    assert descriptor('arm', TABLE['arm']).additional_constraints == 'one of: right, left'
    assert descriptor('lengths', TABLE['lengths']).additional_constraints == (
        '4 values, each within 0.001..2')
    assert descriptor('rotation', TABLE['rotation']).additional_constraints == '3 or 4 values'


@pytest.mark.parametrize('name, text, message', [
    ('rate_hz', '-1', 'rate_hz:=-1: -1.0 is outside 1..5000'),
    ('rate_hz', 'abc', 'rate_hz:=abc: expected a number'),
    ('rate_hz', 'nan', 'rate_hz:=nan: nan is outside 1..5000'),
    ('rate_hz', '', 'rate_hz:=: expected a number'),
    ('baud', '9600.5', 'baud:=9600.5: expected an integer'),
])
def test_a_bad_launch_argument_is_refused_in_one_line_naming_it(name, text, message):
    assert refusal(launch_argument, TABLE, name, text) == message


def test_a_launch_argument_is_taken_as_its_parameter():
    assert launch_argument(TABLE, 'rate_hz', '250') == 250.0
    assert launch_argument(TABLE, 'baud', '9600') == 9600


# -- a node's parameters -----------------------------------------------------------------------


def test_defaults_are_declared_when_nothing_is_given(make_node):
    node = make_node()
    values = declare_parameters(node, TABLE)
    assert values == {name: spec.default for name, spec in TABLE.items()}
    assert node.get_parameter('baud').type_ == Parameter.Type.INTEGER
    assert node.get_parameter('lengths').type_ == Parameter.Type.DOUBLE_ARRAY


def test_given_values_are_checked_and_returned(make_node):
    node = make_node(arm='left', rate_hz=250.0, lengths=[0.5, 0.5, 0.5, 0.5], low_latency=True)
    values = declare_parameters(node, TABLE)
    assert (values['arm'], values['rate_hz'], values['lengths'], values['low_latency']) == (
        'left', 250.0, [0.5, 0.5, 0.5, 0.5], True)


def test_integers_are_taken_for_doubles_at_start_up_and_at_run_time(make_node):
    node = make_node(rate_hz=250, lengths=[1, 1, 1, 1])
    values = declare_parameters(node, TABLE)
    assert values['rate_hz'] == 250.0 and type(values['rate_hz']) is float
    assert node.get_parameter('rate_hz').type_ == Parameter.Type.DOUBLE
    assert node.get_parameter('lengths').value == [1.0, 1.0, 1.0, 1.0]
    result = node.set_parameters([Parameter('rate_hz', value=100)])[0]
    assert result.successful, result.reason
    parameter = node.get_parameter('rate_hz')
    assert (parameter.type_, parameter.value) == (Parameter.Type.DOUBLE, 100.0)
    assert parameter.get_parameter_value().type == ParameterType.PARAMETER_DOUBLE


@pytest.mark.parametrize('overrides, message', [
    ({'baud': 'fast'}, "parameter baud: expected an integer, got 'fast'"),
    ({'baud': 9600.5}, 'parameter baud: expected an integer, got 9600.5'),
    ({'baud': True}, 'parameter baud: expected an integer, got True'),
    ({'low_latency': 1}, 'parameter low_latency: expected true or false, got 1'),
    ({'port': 5}, 'parameter port: expected a string, got 5'),
    ({'rate_hz': 'high'}, "parameter rate_hz: expected a number, got 'high'"),
    ({'rate_hz': [1.0, 2.0]}, 'parameter rate_hz: expected a number, got [1.0, 2.0]'),
    ({'lengths': 0.5}, 'parameter lengths: expected a list of 4 (a number), got 0.5'),
    ({'limits': [1.5, 2.5]}, 'parameter limits: expected a list of 2 (an integer), got '
                             '[1.5, 2.5]'),
    ({'rate_hz': 0}, 'parameter rate_hz: 0.0 is outside 1..5000'),
    ({'baud': 100}, 'parameter baud: 100 is outside 1200..12000000'),
    ({'arm': 'middle'}, "parameter arm: 'middle' is not one of right, left"),
    ({'lengths': [0.1, 0.2]}, 'parameter lengths: expected 4 values, got 2'),
    ({'corner': [5.0, 5.0]}, 'parameter corner: expected 3 values, got 2'),
    ({'corner': 5.0}, 'parameter corner: expected a list of 3 (a number), got 5.0'),
])
def test_a_bad_given_value_is_refused_in_one_line_naming_it(make_node, overrides, message):
    assert refusal(declare_parameters, make_node(**overrides), TABLE) == message


@pytest.mark.parametrize('given, nearest', [
    ('rate', 'rate_hz'), ('Rate_Hz', 'rate_hz'), ('bawd', 'baud'), ('lenghts', 'lengths'),
    ('use_sim_tim', 'use_sim_time'),
])
def test_a_misspelt_name_is_refused_naming_the_nearest(make_node, given, nearest):
    node = make_node(**{given: 1})
    assert refusal(declare_parameters, node, TABLE) == (
        f'unknown parameter {given} for {node.get_fully_qualified_name()}: did you mean '
        f'{nearest}?')


def test_a_name_far_from_all_is_refused_pointing_to_help(make_node):
    node = make_node(completely_different=1)
    assert refusal(reject_unknown, node, TABLE).endswith(
        'completely_different for ' + node.get_fully_qualified_name()
        + ': see --help for the parameters')


def test_the_standard_ros_parameters_are_accepted(make_node):
    node = make_node(use_sim_time=False, start_type_description_service=False,
                     **{'qos_overrides./wrench.subscription.depth': 5})
    reject_unknown(node, TABLE)
    assert declare_parameters(node, TABLE)['baud'] == 1_000_000


def test_integer_lists_become_double_lists_at_run_time(make_node):
    node = make_node()
    declare_parameters(node, TABLE)
    result = node.set_parameters([Parameter('lengths', value=[1, 2, 1, 2])])[0]
    assert result.successful, result.reason
    assert node.get_parameter('lengths').value == [1.0, 2.0, 1.0, 2.0]


# -- params files ------------------------------------------------------------------------------


def write(tmp_path, text):
    path = tmp_path / 'params.yaml'
    path.write_text(text)
    return path


def test_a_params_file_names_its_nodes_and_lines(tmp_path):
    path = write(tmp_path, '/**:\n  ros__parameters:\n    baud: 9600\n'
                 'right:\n  kraft_master_node:\n    ros__parameters:\n      arm: right\n')
    params_file = read_params_file(path)
    assert params_file.nodes == (('/**', 2), ('/right/kraft_master_node', 6))


@pytest.mark.parametrize('full_name, matches', [
    ('/right/kraft_master_node', True), ('/kraft_master_node', False),
    ('/left/kraft_master_node', False),
])
def test_a_params_file_holds_parameters_only_for_the_nodes_it_names(tmp_path, full_name,
                                                                    matches):
    path = write(tmp_path, 'right:\n  kraft_master_node:\n    ros__parameters:\n      baud: 1\n')
    params_file = read_params_file(path)
    if matches:
        params_file.check_names(full_name)
    else:
        assert refusal(params_file.check_names, full_name) == (
            f'{path}: no ros__parameters for {full_name}; the file sets '
            '/right/kraft_master_node (line 3) (use /** for any node)')


@pytest.mark.parametrize('key, full_name', [
    ('/**', '/right/kraft_master_node'), ('/*/kraft_master_node', '/right/kraft_master_node'),
    ('kraft_master_*', '/kraft_master_node'), ('/**/kraft_master_node', '/a/b/kraft_master_node'),
])
def test_wildcards_in_node_names(tmp_path, key, full_name):
    path = write(tmp_path, f'{key}:\n  ros__parameters:\n    baud: 1\n')
    read_params_file(path).check_names(full_name)


@pytest.mark.parametrize('text, message', [
    ('/**:\n  ros_parameters:\n    baud: 1\n',
     "line 2: 'ros_parameters': did you mean ros__parameters?"),
    ('/**:\n  ros__parameters:\n    lengths: [1, 0.5, 0.5, 0.5]\n',
     'line 3: a list must not mix integers and decimals (write 1.0 for 1)'),
    ('ros__parameters:\n  baud: 1\n',
     'line 1: ros__parameters must sit under a node name such as /**'),
    ('/**:\n  ros__parameters: 5\n', 'line 2: ros__parameters must map parameter names to values'),
    ('/**:\n  baud: 1\n', "line 1: '/**' has no ros__parameters under it"),
    ('- a\n- b\n', 'line 1: expected node names, each with ros__parameters under it'),
])
def test_a_bad_params_file_is_refused_in_one_line_with_its_line(tmp_path, text, message):
    path = write(tmp_path, text)
    assert refusal(read_params_file, path) == f'{path} {message}'


def test_a_params_file_that_is_not_yaml_is_refused_in_one_line_with_its_line(tmp_path):
    path = write(tmp_path, '/**:\n  ros__parameters:\n    port: "sim\n')
    message = refusal(read_params_file, path)
    assert message.startswith(f'{path} line 4: not valid YAML: ')


def test_an_empty_params_file_is_refused(tmp_path):
    path = write(tmp_path, '')
    assert refusal(read_params_file, path) == f'{path}: the params file is empty'


def test_a_missing_params_file_is_refused_in_one_line(tmp_path):
    path = tmp_path / 'nowhere.yaml'
    assert refusal(read_params_file, path) == (
        f'{path}: cannot read the params file: No such file or directory')


# -- --help ------------------------------------------------------------------------------------


def test_usage_lists_every_parameter_with_its_default_wrapped_at_99_columns():
    text = usage('kraft_test', 'kraft_test: a test node.', TABLE)
    lines = text.splitlines()
    assert lines[0].startswith('usage: kraft_test [--help] [--ros-args')
    assert 'kraft_test: a test node.' in lines
    assert all(len(line) <= 99 for line in lines if line.startswith('  '))
    for shown in ('arm [right]:', 'baud [1000000]:', 'rate_hz [1000]:', 'low_latency [false]:',
                  'lengths [[0.1, 0.2, 0.3, 0.4]]:', "frame_prefix ['']:"):
        assert any(line.startswith('  ' + shown) for line in lines), shown
    assert '  rate_hz [1000]: Loop rate (Hz). Settable at run time.' in lines
    assert '  baud [1000000]: Baud rate (bit/s).' in lines
    port = lines.index(next(line for line in lines if line.startswith('  port [')))
    assert lines[port + 1].startswith('      ')  # a long description goes on, indented
    assert lines[-1] == ('Example: kraft_test --ros-args -p arm:=... '
                         '--params-file my_params.yaml')
