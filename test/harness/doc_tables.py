# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""What the doc pages' parameter tables and test names are checked against."""
import re

from harness import REPO


def table_rows(page, heading):
    """
    Return {name: (default, range, run-time)} of the parameter table in section `heading`.

    run-time is the cell of a run-time column (yes or no), None in a table without one.
    """
    section = page.split(f'\n## {heading}\n', 1)[1].split('\n## ', 1)[0]
    return {m.group(1): (m.group(2).strip(), m.group(3).strip(), m.group(4)) for m in re.finditer(
        r'^\| `([a-z_.]+)` \| ([^|]+) \| ([^|]*) \| (?:(yes|no) \| )?[^|]+ \|$', section,
        re.MULTILINE)}


def _number(value):
    """Return a number as the tables write it: integers as integers."""
    if isinstance(value, int) or float(value).is_integer() and abs(value) < 1e15:
        return str(int(value))
    return f'{value:g}'


def _shown(value):
    """Return a default as the tables write it."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list):
        return '`[' + ', '.join(_number(x) for x in value) + ']`'
    return f'`{value}`' if isinstance(value, str) else f'`{_number(value)}`'


def expected_row(spec, run_time_column=False):
    """Return the (default, range, run-time) cells a parameter's Spec gives."""
    bounds = (', '.join(spec.choices) if spec.choices
              else '' if spec.low is None else f'{_number(spec.low)} .. {_number(spec.high)}')
    run_time = ('no' if spec.read_only else 'yes') if run_time_column else None
    return _shown(spec.default), bounds, run_time


def undefined_tests(page, test_files):
    """Return the `test_...` names `page` cites that none of `test_files` (names) defines."""
    named = set(re.findall(r'`(test_\w+)`', page))
    assert named, 'the page names no test'
    defined = set()
    for name in test_files:
        for path in (REPO / 'test').rglob(name):  # wherever the test files are moved
            defined |= set(re.findall(r'^def (test_\w+)', path.read_text(), re.MULTILINE))
    return named - defined
