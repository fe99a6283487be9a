# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""report_data: a session bag read into per-arm arrays."""

from kraft_master_driver.bag.recorder import BagRecorder
from kraft_master_driver.bag.samples import simulate_samples, write_samples
from kraft_master_driver.tools import report_data


def test_old_relative_diagnostics_are_read_from_the_arms_own_topic(tmp_path):
    bag = tmp_path / 'old'
    with BagRecorder(bag, 'sqlite3') as recorder:
        write_samples(recorder, '/left', simulate_samples(2000, 'left', seed=1),
                      diagnostics_every=500)
        write_samples(recorder, '', simulate_samples(2000, 'right', seed=2),
                      diagnostics_every=250)
    root, left = report_data.read_arms(bag)
    assert (root.namespace, len(root.diagnostics)) == ('', 8)
    assert (left.namespace, len(left.diagnostics)) == ('/left', 4)
