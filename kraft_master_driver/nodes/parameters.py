# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
ROS parameters of the package's nodes as users type them, and the checks that refuse bad ones.

A node describes its parameters in a table of Spec. declare_parameters() refuses a parameter
given for the node that the table does not know (naming the nearest known one), accepts an
integer wherever a floating-point value is expected (at start-up and at run time: the parameter
stays DOUBLE), and checks every value against its Spec. run_time_changes() checks a set at run
time the same way, and refuses one of a parameter fixed at start-up. read_params_file() checks a
params file as rcl would read it; usage() is a node's --help text. Every refusal is a
ParameterError of one line; node_process.run_node() prints it and exits 1. launch_argument()
checks a launch file's argument that gives a parameter its value, as the node would.
"""
import difflib
import math
import re
import textwrap
from typing import NamedTuple

from kraft_master_driver.core.calibration import yaml_fault
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
import rclpy.exceptions
from rclpy.parameter import Parameter
import yaml

# Parameters every rclpy node may be given, besides a node's own.
STANDARD_PARAMETERS = ('use_sim_time', 'start_type_description_service')
STANDARD_PREFIXES = ('qos_overrides.',)
PARAMS_KEY = 'ros__parameters'
MIXED_NUMBERS = {'tag:yaml.org,2002:int', 'tag:yaml.org,2002:float'}
_INTEGER_TO_DOUBLE = {Parameter.Type.INTEGER: Parameter.Type.DOUBLE,
                      Parameter.Type.INTEGER_ARRAY: Parameter.Type.DOUBLE_ARRAY}
_KIND_NAMES = {bool: 'true or false', int: 'an integer', float: 'a number', str: 'a string'}


class Spec(NamedTuple):
    """One parameter: default, description with units, range, whether fixed at start-up."""

    default: object
    description: str
    read_only: bool = True
    low: float = None
    high: float = None
    choices: tuple = ()
    length: object = None  # of a list value: a number, or a tuple of the numbers allowed


class ParameterError(ValueError):
    """A parameter or params file the node cannot run with; the message names it."""


def _item_type(spec):
    """Python type of the value, or of each element of a list value."""
    default = spec.default
    return type(default[0]) if isinstance(default, list) else type(default)


def _floating(spec):
    return _item_type(spec) is float


def descriptor(name, spec):
    """Return the ParameterDescriptor of a Spec: its type comes from the default."""
    result = ParameterDescriptor(name=name, description=spec.description,
                                 read_only=spec.read_only)
    if spec.choices:
        result.additional_constraints = 'one of: ' + ', '.join(spec.choices)
    if spec.length:
        result.additional_constraints = f'{_lengths_text(spec)} values'
        if spec.low is not None:
            result.additional_constraints += (
                f', each within {_number(spec.low)}..{_number(spec.high)}')
    elif spec.low is not None and isinstance(spec.default, int):
        result.integer_range = [IntegerRange(
            from_value=int(spec.low), to_value=int(spec.high), step=1)]
    elif spec.low is not None:
        result.floating_point_range = [FloatingPointRange(
            from_value=float(spec.low), to_value=float(spec.high), step=0.0)]
    return result


def _lengths(spec):
    """Return the lengths a list parameter may have."""
    return spec.length if isinstance(spec.length, tuple) else (spec.length,)


def _lengths_text(spec):
    """Return the lengths a list parameter may have as text: 3, or 3 or 4."""
    return ' or '.join(map(str, _lengths(spec)))


def _number(value):
    """Return a bound or default as people write it: integers without exponent or point."""
    return str(int(value)) if float(value).is_integer() and abs(value) < 1e15 else f'{value:g}'


def check_value(table, name, value):
    """Return `value` if it suits parameter `name` of `table`, else raise ParameterError."""
    spec = table[name]
    if value is None:
        raise ParameterError(f'parameter {name}: no value (an empty list has no type)')
    if spec.choices and value not in spec.choices:
        raise ParameterError(
            f'parameter {name}: {value!r} is not one of {", ".join(spec.choices)}')
    if spec.length is not None:
        values = list(value)
        if len(values) not in _lengths(spec):
            raise ParameterError(
                f'parameter {name}: expected {_lengths_text(spec)} values, got {len(values)}')
        if spec.low is not None:
            for item in values:
                _check_range(name, spec, item)
        return values
    if spec.low is not None:
        _check_range(name, spec, value)
    return value


def launch_argument(table, name, text):
    """
    Return launch argument `name`:=`text` as the number parameter `name` of `table` takes it.

    A text that is not such a number, or a value check_value() refuses, raises ParameterError
    of one line naming the argument: `contact_damping:=-1: -1.0 is outside 0..100`.
    """
    kind = type(table[name].default)
    try:
        value = kind(text)
    except ValueError:
        raise ParameterError(f'{name}:={text}: expected {_KIND_NAMES[kind]}') from None
    try:
        return check_value(table, name, value)
    except ParameterError as error:
        reason = str(error).removeprefix(f'parameter {name}: ')
        raise ParameterError(f'{name}:={text}: {reason}') from None


def _check_range(name, spec, value):
    if not (math.isfinite(value) and spec.low <= value <= spec.high):
        raise ParameterError(f'parameter {name}: {value!r} is outside '
                             f'{_number(spec.low)}..{_number(spec.high)}')


def _as_double(parameter):
    """Return an INTEGER (array) parameter as the DOUBLE (array) of the same values."""
    value = parameter.value
    if parameter.type_ == Parameter.Type.INTEGER_ARRAY:
        value = [float(x) for x in value]  # a list, or an array.array from the service
    else:
        value = float(value)
    return Parameter(parameter.name, _INTEGER_TO_DOUBLE[parameter.type_], value)


def coerce_integers(table, parameters):
    """Return `parameters` with integers given for floating-point parameters made doubles."""
    return [_as_double(p) if p.name in table and _floating(table[p.name])
            and p.type_ in _INTEGER_TO_DOUBLE else p for p in parameters]


def _check_type(name, spec, parameter):
    """Raise ParameterError if an override's type cannot stand for parameter `name`."""
    value = parameter.value
    if value is None:
        return
    kind = _item_type(spec)
    values = value if isinstance(value, (list, tuple)) else [value]
    if isinstance(spec.default, list) != isinstance(value, (list, tuple)) or not all(
            type(item) is kind for item in values):
        expected = _KIND_NAMES[kind]
        if isinstance(spec.default, list):
            count = f' of {_lengths_text(spec)}' if spec.length else ''
            expected = f'a list{count} ({expected})'
        raise ParameterError(f'parameter {name}: expected {expected}, got {value!r}')


def known_names(table):
    """Every parameter name a node with this table accepts."""
    return [*table, *STANDARD_PARAMETERS]


def reject_unknown(node, table):
    """Raise ParameterError naming the first parameter given for `node` that is not known."""
    for name in node._parameter_overrides:
        if name in table or name in STANDARD_PARAMETERS or name.startswith(STANDARD_PREFIXES):
            continue
        known = {known.lower(): known for known in known_names(table)}
        nearest = [known[close] for close in difflib.get_close_matches(name.lower(), known, n=1)]
        hint = f'did you mean {nearest[0]}?' if nearest else 'see --help for the parameters'
        raise ParameterError(f'unknown parameter {name} for {node.get_fully_qualified_name()}'
                             f': {hint}')


def declare_parameters(node, table, params_files=()):
    """
    Check what `node` was given against `table`, declare every parameter; return the values.

    `params_files` (ParamsFile) must each hold parameters for this node. Integers given for
    floating-point parameters become doubles, now and in later set_parameters calls.
    """
    full_name = node.get_fully_qualified_name()
    for params_file in params_files:
        params_file.check_names(full_name)
    reject_unknown(node, table)
    overrides = node._parameter_overrides
    values = {}
    for name, spec in table.items():
        if name in overrides:
            (overrides[name],) = coerce_integers(table, [overrides[name]])
            _check_type(name, spec, overrides[name])
            check_value(table, name, overrides[name].value)
        try:
            value = node.declare_parameter(name, spec.default, descriptor(name, spec)).value
        except (rclpy.exceptions.InvalidParameterTypeException,
                rclpy.exceptions.InvalidParameterValueException) as error:
            raise ParameterError(f'parameter {name}: {error}') from None
        values[name] = check_value(table, name, value)
    node.add_pre_set_parameters_callback(lambda parameters: coerce_integers(table, parameters))
    return values


def run_time_changes(table, parameters):
    """
    Return {name: checked value} of a run-time set of `parameters` of `table`.

    A read-only parameter, or a value check_value() refuses, raises ParameterError (one line).
    Parameters the table does not know (the standard ones) are left out.
    """
    changes = {}
    for parameter in parameters:
        spec = table.get(parameter.name)
        if spec is None:
            continue
        if spec.read_only:
            raise ParameterError(f'parameter {parameter.name} is read-only')
        changes[parameter.name] = check_value(table, parameter.name, parameter.value)
    return changes


# -- params files ------------------------------------------------------------------------


def _node_pattern(key):
    """Regex of the node names a params file key (/ns/node, /**, /*/node) stands for."""
    tokens = ('/' + key.lstrip('/')).split('/')[1:]
    parts = []
    for token in tokens:
        if token == '**':
            parts.append('(?:/[^/]+)*')
        else:
            parts.append('/' + '[^/]*'.join(map(re.escape, token.split('*'))))
    return re.compile(''.join(parts))


class ParamsFile(NamedTuple):
    """A params file that parsed: its path and the node names (with their lines) it sets."""

    path: str
    nodes: tuple  # (node name key, line)

    def check_names(self, full_name):
        """Raise ParameterError unless one of this file's node names matches `full_name`."""
        if not any(_node_pattern(key).fullmatch(full_name) for key, _ in self.nodes):
            names = ', '.join(f'{key} (line {line})' for key, line in self.nodes)
            raise ParameterError(
                f'{self.path}: no {PARAMS_KEY} for {full_name}; the file sets {names} '
                '(use /** for any node)')


def _where(path, node):
    return f'{path} line {node.start_mark.line + 1}'


def _check_sequences(path, node):
    """Raise ParameterError at a list of integers and decimals (rcl refuses those)."""
    if isinstance(node, yaml.MappingNode):
        for _, value in node.value:
            _check_sequences(path, value)
    elif isinstance(node, yaml.SequenceNode):
        if {item.tag for item in node.value} == MIXED_NUMBERS:
            raise ParameterError(f'{_where(path, node)}: a list must not mix integers and '
                                 'decimals (write 1.0 for 1)')


def _has_params(node):
    """Whether a params file mapping holds ros__parameters at some depth."""
    return isinstance(node, yaml.MappingNode) and any(
        str(key.value) == PARAMS_KEY or _has_params(value) for key, value in node.value)


def _node_entries(path, mapping, prefix=''):
    """Yield (node name, line) of each entry of a params file mapping; ParameterError if bad."""
    if not isinstance(mapping, yaml.MappingNode):
        raise ParameterError(f'{_where(path, mapping)}: expected node names, each with '
                             f'{PARAMS_KEY} under it')
    for key_node, value in mapping.value:
        key = str(key_node.value)
        if key == PARAMS_KEY:
            if not prefix:
                raise ParameterError(f'{_where(path, key_node)}: {PARAMS_KEY} must sit under '
                                     'a node name such as /**')
            if not isinstance(value, yaml.MappingNode):
                raise ParameterError(f'{_where(path, value)}: {PARAMS_KEY} must map parameter '
                                     'names to values')
            _check_sequences(path, value)
            yield prefix, key_node.start_mark.line + 1
        elif _has_params(value):
            yield from _node_entries(path, value, f'{prefix}/{key.strip("/")}')
        else:
            children = value.value if isinstance(value, yaml.MappingNode) else []
            misspelt = next((child for child, _ in children if difflib.get_close_matches(
                str(child.value), [PARAMS_KEY], n=1)), None)
            if misspelt is not None:
                raise ParameterError(f'{_where(path, misspelt)}: {misspelt.value!r}: did you '
                                     f'mean {PARAMS_KEY}?')
            raise ParameterError(f'{_where(path, key_node)}: {key!r} has no {PARAMS_KEY} '
                                 'under it')


def read_params_file(path):
    """Parse a params file as rcl would; return its ParamsFile or raise ParameterError."""
    try:
        with open(path, encoding='utf-8') as stream:
            root = yaml.compose(stream, Loader=yaml.SafeLoader)
    except OSError as error:
        raise ParameterError(f'{path}: cannot read the params file: '
                             f'{error.strerror or error}') from None
    except yaml.YAMLError as error:
        raise ParameterError(yaml_fault(path, error)) from None
    if root is None:
        raise ParameterError(f'{path}: the params file is empty')
    return ParamsFile(str(path), tuple(_node_entries(path, root)))


# -- --help -------------------------------------------------------------------------------


def usage(program, summary, table):
    """Return the --help text of a node: the --ros-args forms and its parameters, briefly."""
    lines = [f'usage: {program} [--help] [--ros-args [-p NAME:=VALUE ...] '
             '[--params-file FILE] [-r __ns:=/NAMESPACE]]', '', summary, '',
             'Parameters (-p name:=value, or under ros__parameters in a params file; '
             'default in brackets):']
    for name, spec in table.items():
        default = spec.default
        if isinstance(default, bool):
            shown = str(default).lower()
        elif isinstance(default, list):
            shown = '[' + ', '.join(_number(x) if not isinstance(x, str) else x
                                    for x in default) + ']'
        elif isinstance(default, (int, float)):
            shown = _number(default)
        else:
            shown = repr(default) if not default else default
        text = f'{name} [{shown}]: {spec.description}'
        if not spec.read_only:
            text += ' Settable at run time.'
        lines += textwrap.wrap(text, 99, initial_indent='  ', subsequent_indent='      ')
    lines += ['', f'Example: {program} --ros-args -p {next(iter(table))}:=... '
              '--params-file my_params.yaml']
    return '\n'.join(lines)
