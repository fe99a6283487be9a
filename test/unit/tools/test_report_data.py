# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""report_data: a session bag read into per-arm arrays, and the quaternions of its poses."""
import math

from kraft_master_driver.bag.recorder import BagRecorder
from kraft_master_driver.bag.samples import simulate_samples, write_samples
from kraft_master_driver.core import kinematics
from kraft_master_driver.tools import report_data
import numpy as np


def test_batch_quaternions_equal_the_scalar_ones():
    rng = np.random.default_rng(10)
    theta = rng.uniform(-math.pi, math.pi, (4000, 6))
    rotations = kinematics.forward(theta)[:, :3, :3]
    # Rotations of half a turn reach every branch of the conversion.
    flips = np.array([np.diag(d) for d in ((1, -1, -1), (-1, 1, -1), (-1, -1, 1))] +
                     [[[0, 1, 0], [1, 0, 0], [0, 0, -1]]])  # half a turn about x = y: a tie
    rotations = np.concatenate([rotations, flips])
    expected = np.array([kinematics.rotation_to_quaternion(r) for r in rotations])
    np.testing.assert_allclose(report_data.quaternions(rotations), expected, atol=1e-12)


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
