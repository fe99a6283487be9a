# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Rotations: roll, pitch, yaw and quaternions, rotation vectors, integration, batches."""
import math

from hypothesis import given, settings as hypothesis_settings, strategies as st
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.rotations import (
    integrate_quaternion, quaternion_to_rotation, rotation_from_vector, rotation_parameter,
    rotation_to_quaternion, rotation_vector, rotations_to_quaternions, rpy_to_rotation)
import numpy as np
import pytest


def about_z(angle):
    """Return the quaternion (x, y, z, w) of a turn of `angle` rad about z."""
    return (0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2))


def test_roll_pitch_yaw_and_quaternion_give_the_same_rotation():
    yaw = rotation_parameter('r', [0.0, 0.0, math.pi / 2])
    np.testing.assert_allclose(yaw @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(rotation_parameter('r', about_z(math.pi / 2)), yaw, atol=1e-12)
    pitch = rpy_to_rotation(0.0, math.pi / 2, 0.0)
    np.testing.assert_allclose(pitch @ [1.0, 0.0, 0.0], [0.0, 0.0, -1.0], atol=1e-12)


@pytest.mark.parametrize('values, fragment', [
    ([1.0, 2.0], '3 finite values'), ([0.0, math.nan, 0.0], '3 finite values'),
    ([0.0, 0.0, 0.0, 2.0], 'not of unit length')])
def test_a_bad_rotation_parameter_is_refused_naming_it(values, fragment):
    with pytest.raises(ValueError, match=f'base_rotation.*{fragment}|{fragment}'):
        rotation_parameter('base_rotation', values)


@hypothesis_settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3), st.floats(0.0, math.pi - 1e-3))
def test_rotation_vector_inverts_rodrigues(axis, angle):
    axis = np.array(axis)
    if np.linalg.norm(axis) < 1e-3:
        return
    vector = angle * axis / np.linalg.norm(axis)
    np.testing.assert_allclose(rotation_vector(rotation_from_vector(vector)), vector, atol=1e-7)


def test_rotation_vector_of_a_half_turn():
    half_turn = quaternion_to_rotation((0.0, 1.0, 0.0, 0.0))
    np.testing.assert_allclose(np.abs(rotation_vector(half_turn)), [0.0, math.pi, 0.0],
                               atol=1e-9)


@hypothesis_settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-3, 3), min_size=3, max_size=3), st.floats(0.0, 2.0))
def test_quaternion_integration_turns_by_the_angle_about_the_axis(rate, seconds):
    rate = np.array(rate)
    q = integrate_quaternion((0.0, 0.0, 0.0, 1.0), rate, seconds)
    angle = np.linalg.norm(rate) * seconds
    assert np.linalg.norm(q) == pytest.approx(1.0)
    assert abs(q[3]) == pytest.approx(abs(math.cos(angle / 2)), abs=1e-9)
    if math.sin(angle / 2) > 1e-6:
        np.testing.assert_allclose(np.array(q[:3]) / math.sin(angle / 2),
                                   rate / np.linalg.norm(rate), atol=1e-6)


def test_quaternion_integration_composes_in_the_base_frame():
    about_z = integrate_quaternion((0.0, 0.0, 0.0, 1.0), (0.0, 0.0, math.pi / 2), 1.0)
    then_about_x = integrate_quaternion(about_z, (math.pi / 2, 0.0, 0.0), 1.0)
    # Rx(90) Rz(90) as (x, y, z, w).
    np.testing.assert_allclose(then_about_x, [0.5, -0.5, 0.5, 0.5], atol=1e-12)


def test_batch_quaternions_equal_the_scalar_ones():
    rng = np.random.default_rng(10)
    theta = rng.uniform(-math.pi, math.pi, (4000, 6))
    rotations = kinematics.forward(theta)[:, :3, :3]
    # Rotations of half a turn reach every branch of the conversion.
    flips = np.array([np.diag(d) for d in ((1, -1, -1), (-1, 1, -1), (-1, -1, 1))] +
                     [[[0, 1, 0], [1, 0, 0], [0, 0, -1]]])  # half a turn about x = y: a tie
    rotations = np.concatenate([rotations, flips])
    expected = np.array([rotation_to_quaternion(r) for r in rotations])
    np.testing.assert_allclose(rotations_to_quaternions(rotations), expected, atol=1e-12)
