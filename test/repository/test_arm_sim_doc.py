# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""doc/arm-sim.md says what kraft_master_arm_sim does: its parameters and its tests."""
import re

from harness import REPO
from kraft_master_driver.nodes.arm_sim import PARAMETERS
import pytest

PAGE = (REPO / 'doc' / 'arm-sim.md').read_text()
ROWS = {m.group(1): (m.group(2).strip(), m.group(3).strip()) for m in re.finditer(
    r'^\| `([a-z_.]+)` \| ([^|]+) \| ([^|]*) \| [^|]+ \|$',
    PAGE.split('## Parameters', 1)[1].split('\n## ', 1)[0], re.MULTILINE)}


def number(value):
    """Return a number as the table writes it: integers as integers."""
    if isinstance(value, int) or float(value).is_integer() and abs(value) < 1e15:
        return str(int(value))
    return f'{value:g}'


def shown(value):
    """Return a default as the table writes it."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list):
        return '`[' + ', '.join(number(x) for x in value) + ']`'
    return f'`{value}`' if isinstance(value, str) else f'`{number(value)}`'


@pytest.mark.parametrize('name', PARAMETERS)
def test_every_parameter_is_in_the_table_with_its_default_and_range(name):
    assert name in ROWS, f'doc/arm-sim.md has no row for parameter {name}'
    spec = PARAMETERS[name]
    bounds = (', '.join(spec.choices) if spec.choices
              else '' if spec.low is None else f'{number(spec.low)} .. {number(spec.high)}')
    assert ROWS[name] == (shown(spec.default), bounds)


def test_the_table_has_no_stale_parameter():
    assert ROWS and set(ROWS) <= set(PARAMETERS)


def test_every_test_the_page_names_exists():
    named = set(re.findall(r'`(test_\w+)`', PAGE))
    defined = set()
    for name in ('test_arm_physics.py', 'test_arm_sim_node.py'):
        for path in (REPO / 'test').rglob(name):
            defined |= set(re.findall(r'^def (test_\w+)', path.read_text(), re.MULTILINE))
    assert named and named <= defined, named - defined
