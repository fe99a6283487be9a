# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The README documents every parameter of the node, with its real default."""
import re

from driver_harness import REPO
from kraft_master_driver.nodes.driver_parameters import PARAMETERS
from kraft_master_driver.simulation.simulator import OPERATORS
import pytest

README = (REPO / 'README.md').read_text()
ROWS = {m.group(1): m.groups()[1:] for m in re.finditer(
    r'^\| `([a-z_.]+)` \| ([a-z\[\]0-9]+) \| ([^|]+) \| ([^|]*) \|', README, re.MULTILINE)}


def number(value):
    """Return a number as the table writes it: integers as integers (1000000, not 1e+06)."""
    if isinstance(value, int) or float(value).is_integer() and abs(value) < 1e15:
        return str(int(value))
    return f'{value:g}'


def readme_default(value):
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list):
        return '`[' + ', '.join(number(x) for x in value) + ']`'
    if isinstance(value, str):
        return f'`{value}`' if value else "`''`"
    return f'`{number(value)}`'


def readme_type(default):
    kind = type(default[0]) if isinstance(default, list) else type(default)
    name = {bool: 'bool', int: 'int', float: 'double', str: 'string'}[kind]
    return f'{name}[{len(default)}]' if isinstance(default, list) else name


def readme_range(spec):
    if spec.choices:
        return ', '.join(spec.choices)
    return '' if spec.low is None else f'{number(spec.low)} .. {number(spec.high)}'


@pytest.mark.parametrize('name', PARAMETERS)
def test_every_parameter_is_in_the_readme_table_with_its_default(name):
    assert name in ROWS, f'README.md has no row for parameter {name}'
    spec = PARAMETERS[name]
    kind, default, bounds = (cell.strip() for cell in ROWS[name])
    assert (kind, default, bounds) == (
        readme_type(spec.default), readme_default(spec.default), readme_range(spec))


def test_integers_show_as_integers():
    assert [cell.strip() for cell in ROWS['baud'][1:]] == ['`1000000`', '1200 .. 12000000']
    assert 'e+' not in ''.join(''.join(cells) for cells in ROWS.values())


def test_the_readme_table_has_no_stale_parameter():
    assert set(ROWS) <= set(PARAMETERS)


@pytest.mark.parametrize('command', ['make demo', 'make test'])
def test_readme_starts_with_the_two_commands(command):
    assert command in README[:1500]


def test_the_simulator_section_names_every_operator():
    section = README.split('## The simulated hand controller', 1)[1].split('\n## ', 1)[0]
    listed = re.search(r'\(`--operator ([^)]*)\)', section).group(1)
    assert re.findall(r'`?(\w+)`', listed) == list(OPERATORS)
