# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Tests of the rate-mode command (core.rate_control)."""
from math import nan

from harness.joints import random_theta
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.rate_control import rate_command
import numpy as np
import pytest


@pytest.mark.parametrize('seed', range(10))
def test_rate_command_is_the_scaled_pose_difference(seed):
    rng = np.random.default_rng(400 + seed)
    pose, centre = kinematics.forward(random_theta(rng)), kinematics.forward(random_theta(rng))
    dp, w = kinematics.pose_difference(pose, centre)
    v_cmd, w_cmd = rate_command(pose, centre, 2.0, 0.5)
    assert v_cmd.shape == w_cmd.shape == (3,)
    np.testing.assert_array_equal(v_cmd, 2.0 * dp)
    np.testing.assert_array_equal(w_cmd, 0.5 * w)


def test_rate_command_paper_example():
    pose = kinematics.forward(np.radians([-25, 40, -100, -35, 10, 20]))
    centre = kinematics.forward(np.radians([0, 90, -90, 0, 0, 0]))
    v, w = rate_command(pose, centre, 1.0, 1.0)
    np.testing.assert_allclose(v, np.array([22.293, -118.805, -281.387]) * 1e-3, atol=2e-6)
    np.testing.assert_allclose(w, (-0.3574, 0.5958, -0.9987), atol=2e-4)


def test_rate_command_dead_band_shrinks_offsets_continuously():
    centre = kinematics.forward(np.radians([0, 60, -100, 0, 10, 0]))
    pose = centre.copy()
    pose[:3, 3] += (0.003, 0.004, 0.0)  # 5 mm
    v, w = rate_command(pose, centre, 2.0, 1.0, linear_dead_band=0.006)
    assert v.tolist() == [0.0, 0.0, 0.0] and w.tolist() == [0.0, 0.0, 0.0]
    v, _ = rate_command(pose, centre, 2.0, 1.0, linear_dead_band=0.002)
    np.testing.assert_allclose(v, 2.0 * np.array([0.003, 0.004, 0.0]) * (3.0 / 5.0), atol=1e-12)
    v_edge, _ = rate_command(pose, centre, 2.0, 1.0, linear_dead_band=0.005 - 1e-12)
    assert np.linalg.norm(v_edge) < 1e-10


def test_rate_command_non_finite_pose_gives_zero_and_bad_gains_raise():
    centre = kinematics.forward(np.radians([0, 60, -100, 0, 10, 0]))
    pose = centre.copy()
    pose[0, 3] = nan
    v, w = rate_command(pose, centre, 1.0, 1.0)
    assert v.tolist() == [0.0, 0.0, 0.0] and w.tolist() == [0.0, 0.0, 0.0]
    for bad in ({'linear_gain': nan}, {'angular_gain': 'fast'}, {'linear_dead_band': -0.1}):
        args = {'linear_gain': 1.0, 'angular_gain': 1.0, **bad}
        with pytest.raises(ValueError, match=next(iter(bad))):
            rate_command(centre, centre, **args)
