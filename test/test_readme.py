# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The README documents every parameter of the node, with its real default."""
import re

from driver_harness import REPO
from kraft_master_driver.node import PARAMETERS
import pytest

README = (REPO / 'README.md').read_text()
ROWS = {m.group(1): m.group(2) for m in re.finditer(
    r'^\| `([a-z_.]+)` \| [a-z\[\]0-9]+ \| ([^|]+) \|', README, re.MULTILINE)}


def readme_default(value):
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list):
        return '`[' + ', '.join(f'{x:g}' for x in value) + ']`'
    if isinstance(value, str):
        return f'`{value}`' if value else "`''`"
    return f'`{value:g}`'


@pytest.mark.parametrize('name', PARAMETERS)
def test_every_parameter_is_in_the_readme_table_with_its_default(name):
    assert name in ROWS, f'README.md has no row for parameter {name}'
    assert ROWS[name].strip() == readme_default(PARAMETERS[name].default)


def test_the_readme_table_has_no_stale_parameter():
    assert set(ROWS) <= set(PARAMETERS)


@pytest.mark.parametrize('command', ['make demo', 'make test'])
def test_readme_starts_with_the_two_commands(command):
    assert command in README[:1500]
