# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""doc/arm-sim.md says what kraft_master_arm_sim does: its parameters and its tests."""
from harness import REPO
from harness.doc_tables import expected_row, table_rows, undefined_tests
from kraft_master_driver.nodes.arm_sim import PARAMETERS
import pytest

PAGE = (REPO / 'doc' / 'arm-sim.md').read_text()
ROWS = table_rows(PAGE, 'Parameters')


@pytest.mark.parametrize('name', PARAMETERS)
def test_every_parameter_is_in_the_table_with_its_default_and_range(name):
    assert name in ROWS, f'doc/arm-sim.md has no row for parameter {name}'
    assert ROWS[name] == expected_row(PARAMETERS[name])


def test_the_table_has_no_stale_parameter():
    assert ROWS and set(ROWS) <= set(PARAMETERS)


def test_every_test_the_page_names_exists():
    assert not undefined_tests(PAGE, ('test_panda.py', 'test_arm_sim_node.py'))
