# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""doc/bridge.md says what the bridge and the simulated arm do: parameters, safety tests."""
import re

from harness import REPO
from kraft_master_driver.nodes import slave_sim, teleop
import pytest

PAGE = (REPO / 'doc' / 'bridge.md').read_text()


def table_rows(heading):
    """Return {name: (default, range)} of the parameter table in the section `heading`."""
    section = PAGE.split(f'\n## {heading}\n', 1)[1].split('\n## ', 1)[0]
    return {m.group(1): (m.group(2).strip(), m.group(3).strip()) for m in re.finditer(
        r'^\| `([a-z_.]+)` \| ([^|]+) \| ([^|]*) \| [^|]+ \|$', section, re.MULTILINE)}


TABLES = {'Parameters': teleop.PARAMETERS, 'The simulated arm': slave_sim.PARAMETERS}
ROWS = {heading: table_rows(heading) for heading in TABLES}


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


CASES = [(heading, name) for heading, parameters in TABLES.items() for name in parameters]


@pytest.mark.parametrize('heading, name', CASES)
def test_every_parameter_is_in_the_table_with_its_default_and_range(heading, name):
    rows = ROWS[heading]
    assert name in rows, f'doc/bridge.md, {heading}: no row for parameter {name}'
    spec = TABLES[heading][name]
    bounds = (', '.join(spec.choices) if spec.choices
              else '' if spec.low is None else f'{number(spec.low)} .. {number(spec.high)}')
    assert rows[name] == (shown(spec.default), bounds)


@pytest.mark.parametrize('heading', TABLES)
def test_the_table_has_no_stale_parameter(heading):
    assert ROWS[heading] and set(ROWS[heading]) <= set(TABLES[heading])


def test_every_test_the_page_names_exists():
    named = set(re.findall(r'`(test_\w+)`', PAGE))
    defined = set()
    for name in ('test_teleoperation.py', 'test_teleop_node.py', 'test_slave_sim.py',
                 'test_slave_sim_node.py'):
        for path in (REPO / 'test').rglob(name):  # wherever the test files are moved
            defined |= set(re.findall(r'^def (test_\w+)', path.read_text(), re.MULTILINE))
    assert named and named <= defined, named - defined
