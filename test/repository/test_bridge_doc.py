# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""doc/bridge.md says what the bridge and the simulated arm do: parameters, safety tests."""
from harness import REPO
from harness.doc_tables import expected_row, table_rows, undefined_tests
from kraft_master_driver.nodes import slave_sim, teleop_parameters
import pytest

PAGE = (REPO / 'doc' / 'bridge.md').read_text()
TABLES = {'Parameters': teleop_parameters.PARAMETERS, 'The simulated arm': slave_sim.PARAMETERS}
ROWS = {heading: table_rows(PAGE, heading) for heading in TABLES}
CASES = [(heading, name) for heading, parameters in TABLES.items() for name in parameters]


@pytest.mark.parametrize('heading, name', CASES)
def test_every_parameter_is_in_the_table_with_its_default_and_range(heading, name):
    rows = ROWS[heading]
    assert name in rows, f'doc/bridge.md, {heading}: no row for parameter {name}'
    # The bridge's table says which parameters are settable at run time; the arm's are not.
    assert rows[name] == expected_row(TABLES[heading][name], heading == 'Parameters')


@pytest.mark.parametrize('heading', TABLES)
def test_the_table_has_no_stale_parameter(heading):
    assert ROWS[heading] and set(ROWS[heading]) <= set(TABLES[heading])


def test_every_test_the_page_names_exists():
    assert not undefined_tests(PAGE, ('test_teleoperation.py', 'test_teleop_node.py',
                                      'test_point_mass.py', 'test_slave_sim_node.py'))
