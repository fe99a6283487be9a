# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The gravity model: its regressor against the potential energy, its base parameters."""
from kraft_master_driver.core import gravity, kinematics
from kraft_master_driver.core.gravity import GravityModel, SIMULATED_MASSES, STANDARD_NAMES
import numpy as np
import pytest


def random_poses(count, seed=1):
    rng = np.random.default_rng(seed)
    return rng.uniform(kinematics.JOINT_LIMITS[:, 0], kinematics.JOINT_LIMITS[:, 1], (count, 6))


def potential_energy(theta, standard, arm):
    """U = g * sum over links of (m z of the frame's origin + z of R (m c)), from forward()."""
    energy, transform = 0.0, np.eye(4)
    per_link = dict(zip(gravity.LINKS, np.reshape(standard, (len(gravity.LINKS), 4))))
    for link, row in enumerate(kinematics.dh_table(theta, arm), start=1):
        transform = transform @ kinematics.dh_transform(*row)
        if link in per_link:
            mass, *moment = per_link[link]
            energy += gravity.G * (mass * transform[2, 3] + transform[2, :3] @ moment)
    return energy


@pytest.mark.parametrize('arm', kinematics.ARMS)
def test_the_regressor_is_the_gradient_of_the_potential_energy(arm):
    standard = np.random.default_rng(2).uniform(-0.1, 0.1, len(STANDARD_NAMES))
    step = 1e-6
    for theta in random_poses(5):
        joint = [(potential_energy(theta + step * e, standard, arm)
                  - potential_energy(theta - step * e, standard, arm)) / (2 * step)
                 for e in np.eye(6)]
        expected = kinematics.actuator_torques(joint)[:5]
        np.testing.assert_allclose(gravity.standard_regressor(theta, arm) @ standard, expected,
                                   atol=1e-8)
        assert joint[0] == pytest.approx(0.0, abs=1e-8)  # shoulder yaw turns about gravity


@pytest.mark.parametrize('arm', kinematics.ARMS)
def test_the_base_parameters_give_the_standard_ones_torques_at_any_pose(arm):
    model = GravityModel(arm)
    assert model.names == gravity.BASE_NAMES and model.size == 8
    base = model.base_parameters(SIMULATED_MASSES)
    standard = SIMULATED_MASSES.standard()
    for theta in random_poses(20, seed=3):
        expected = gravity.standard_regressor(theta, arm) @ standard
        np.testing.assert_allclose(model.base_regressor(theta) @ base, expected, atol=1e-12)
        np.testing.assert_allclose(model.holding_torques(theta, base), expected, atol=1e-12)


def test_the_base_groups_the_outer_masses_as_the_links_carry_them():
    # mx2 carries the links further out at L1 from the shoulder; mx3 those beyond the elbow.
    l1, l2 = kinematics.NOMINAL_LENGTHS.l1, kinematics.NOMINAL_LENGTHS.l2
    masses = SIMULATED_MASSES
    base = dict(zip(gravity.BASE_NAMES, GravityModel().base_parameters(masses)))
    outer = masses.link3[0] + masses.link4[0] + masses.link5[0] + masses.link6[0]
    assert base['mx2'] == pytest.approx(masses.link2[1] + l1 * outer)
    assert base['mx3'] == pytest.approx(masses.link3[1] + l2 * (outer - masses.link3[0]))


def test_the_simulated_arm_weighs_about_half_a_newton_metre_on_the_shoulder():
    home = np.radians([0.0, 60.0, -85.0, 0.0, 15.0, 0.0])
    model = GravityModel()
    torques = model.holding_torques(home, model.base_parameters(SIMULATED_MASSES))
    assert 0.2 < torques[1] < 0.8 and 0.2 < torques[2] < 0.8
