# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The launch files' arguments, read from their source: this runs without launch installed.

Each file names the arguments it takes in ARGUMENTS, reads no other, passes an included file
only that file's, and every argument is declared once in all three (one vocabulary).
test/integration/test_launch.py checks the same by running them, where launch is installed.
"""
import ast

from harness import REPO
import pytest

LAUNCH_DIR = REPO / 'launch'
FILES = ('kraft_master.launch.py', 'teleop.launch.py', 'teleop_demo.launch.py')
ARMS = ('right', 'left')


def tree(file_name):
    """Return the parsed source of a launch file."""
    return ast.parse((LAUNCH_DIR / file_name).read_text(), file_name)


def module_constant(file_name, name):
    """Return the literal value of the module-level constant `name` of a launch file."""
    for node in tree(file_name).body:
        if isinstance(node, ast.Assign) and [t.id for t in node.targets] == [name]:
            return ast.literal_eval(node.value)
    raise AssertionError(f'{file_name} has no literal {name}')


def names(node):
    """Return the argument names a string node stands for: f'{arm}_port' for each arm."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, ast.JoinedStr):
        # A name that starts with an arm: f'{arm}_port', f'{arm}_params_file'.
        rest = ''.join(v.value for v in node.values[1:] if isinstance(v, ast.Constant))
        return [arm + rest for arm in ARMS]
    return []


def calls(file_name, function):
    """Return the calls of `function` (a name, or an attribute's last name) in a launch file."""
    return [node for node in ast.walk(tree(file_name)) if isinstance(node, ast.Call)
            and function in (getattr(node.func, 'id', None), getattr(node.func, 'attr', None))]


def declared(file_name):
    """Return the names a launch file declares: declare(defaults, 'name', ...), in order."""
    return [name for call in calls(file_name, 'declare') for name in names(call.args[1])]


@pytest.mark.parametrize('file_name', FILES)
def test_a_launch_file_reads_only_the_arguments_it_takes(file_name):
    taken = module_constant(file_name, 'ARGUMENTS')
    read = [name for call in calls(file_name, 'value') + calls(file_name, 'LaunchConfiguration')
            for name in names(call.args[0])]
    assert read, f'{file_name} reads no argument'
    options = module_constant('kraft_master.launch.py', 'LAUNCH_OPTIONS')
    assert set(read) <= set(taken) | set(options), file_name


def test_every_argument_is_declared_once_in_all_three_files():
    declarations = [name for file_name in FILES for name in declared(file_name)]
    assert len(declarations) == len(set(declarations)), declarations
    # The driver's launch file declares what it takes; the others take from those they include.
    assert declared(FILES[0]) == list(module_constant(FILES[0], 'ARGUMENTS'))
    for file_name in FILES:
        assert set(module_constant(file_name, 'ARGUMENTS')) <= set(declarations), file_name
    for name in ('DeclareLaunchArgument', 'LaunchConfiguration'):
        assert not calls(FILES[1], name) and not calls(FILES[2], name), (
            f'{name} outside kraft_master.launch.py: declare arguments with its declare(), '
            'read them with the value() checked_launch gives')


def test_the_files_share_the_vocabulary():
    driver, teleop, demo = (set(module_constant(f, 'ARGUMENTS')) for f in FILES)
    # teleop.launch.py takes the driver's, but crtk (its CRTK names would be the arm's).
    assert teleop >= driver - {'crtk'} and 'crtk' not in teleop
    assert set(module_constant('teleop.launch.py', 'REFUSED')) == {'crtk'}
    assert demo <= teleop
    assert {'arms', 'arm_model', 'mode', 'sim_operator', 'rsp'} <= demo


@pytest.mark.parametrize('file_name, included', [('teleop.launch.py', 'kraft_master.launch.py'),
                                                 ('teleop_demo.launch.py', 'teleop.launch.py')])
def test_an_included_file_is_passed_only_arguments_it_takes(file_name, included):
    (call,) = calls(file_name, 'scoped_include')
    assert ast.literal_eval(call.args[0]) == included
    passed = call.args[1]
    if isinstance(passed, ast.Dict):
        keys = [name for key in passed.keys if key is not None for name in names(key)]
        keys += [name for value in passed.values if isinstance(value, ast.Dict)
                 for key in value.keys for name in names(key)]
        keys += [name for value in passed.values if isinstance(value, ast.DictComp)
                 for name in names(value.key)]
    else:  # {name: value(name) for name in ARGUMENTS if name in <included>.ARGUMENTS}
        assert isinstance(passed, ast.DictComp)
        (generator,) = passed.generators
        assert ast.unparse(generator.iter) == 'ARGUMENTS'
        assert ast.unparse(generator.ifs[0]).endswith('.ARGUMENTS')
        keys = list(module_constant(included, 'ARGUMENTS'))
    assert keys and set(keys) <= set(module_constant(included, 'ARGUMENTS')), keys
