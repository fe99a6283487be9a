# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The fault suite: one test per row of the fault table, against the installed driver.

Each test injects one fault and asserts the outcome: no crash, zero torque (or the input
refused), a message in the driver's log, a diagnostics counter, recovery once the fault clears,
and nothing lost (every pot frame received is published once and reaches the client). It also
measures, from the commands the simulated device received, the time to zero torque: for a lost
reply, from the last torque command to the zero one that follows; for rejected wrenches, a
killed wrench source and signals, from the fault to the zero-torque run that lasts; with the
device unplugged, until the device's own command timeout zeroes it. And the time to recovery,
from the moment the fault clears to the first torque command. The figures of every file here
collect in one table (harness.faults.FAULT_TABLE); after the run it is printed and written to
fault_table.json in the pytest tmp dir.

One file per group: test_link_faults.py, test_wrench_input.py, test_start_up_parameters.py,
test_run_time_parameters.py, test_process_faults.py; the harness is harness/faults.py. Run the
suite alone with `pytest -m faults`.
"""
import json

from harness.faults import FAULT_TABLE, format_table
import pytest


@pytest.fixture(scope='session', autouse=True)
def fault_table(request, tmp_path_factory):
    """After the run: print FAULT_TABLE and write it to fault_table.json in the tmp dir."""
    yield FAULT_TABLE
    if not FAULT_TABLE:
        return
    path = tmp_path_factory.getbasetemp() / 'fault_table.json'
    path.write_text(json.dumps(FAULT_TABLE, indent=2))
    capture = request.config.pluginmanager.getplugin('capturemanager')
    with capture.global_and_fixture_disabled():
        print(f'\n{format_table(FAULT_TABLE)}\nfault table written to {path}')
