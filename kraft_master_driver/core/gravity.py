# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The arm's weight on its motors, linear in a set of identifiable (base) parameters.

Gravity's torques depend only on each link's mass and first moment (mass times centre of
mass, in the link's DH frame): the standard parameters, four per link. Shoulder yaw turns
about gravity's axis (z0 points up, an assumption: the paper's figures draw no floor), so link
1 adds nothing, and the roll of link 6 is not driven, so its centre of mass is taken on the
roll axis. Not all of the remaining 18 are identifiable from torques: only combinations are
(the base parameters; Gautier, "Numerical calculation of the base inertial parameters of
robots", 1991). They are found numerically here, as Gautier does, from the regressor at random
poses: the columns that raise its rank, in order, and each other column written in them. The
holding torques are then `base_regressor(theta) @ base`, by least squares from static poses
as the dVRK's MTM gravity identification does (Fontanelli, Wang et al.).

Torques here are those of the five motors (actuator coordinates, as the driver writes them)
that hold the arm still against gravity.
"""
from typing import NamedTuple

from kraft_master_driver.core import kinematics
import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

G = 9.81  # m/s^2, along -z0
LINKS = (2, 3, 4, 5, 6)  # the links whose weight the motors carry
# Per link: mass (kg), then first moment m*c along x, y, z of its DH frame (kg*m).
STANDARD_NAMES = tuple(f'{what}{link}' for link in LINKS
                       for what in ('m', 'mx', 'my', 'mz'))
# Link 6's first moment off the roll axis would turn an undriven joint: not modelled.
_MODELLED = [i for i, name in enumerate(STANDARD_NAMES) if name not in ('mx6', 'my6')]
# What the regressor finds identifiable (GravityModel checks it): each first moment grouped
# with the masses and moments further out, e.g. mx2 + L1 (m3 + m4 + m5 + m6).
BASE_NAMES = ('mx2', 'my2', 'mx3', 'my3', 'mx4', 'my4', 'mx5', 'my5')
_RANK_TOLERANCE = 1e-9
_IDENTIFICATION_POSES = 200


class LinkMasses(NamedTuple):
    """The standard parameters of links 2..6: per link (mass kg, first moment x, y, z kg*m)."""

    link2: tuple[float, float, float, float]
    link3: tuple[float, float, float, float]
    link4: tuple[float, float, float, float]
    link5: tuple[float, float, float, float]
    link6: tuple[float, float, float, float]

    def standard(self) -> Array:
        """Return the 20 standard parameters in STANDARD_NAMES order."""
        return np.array([value for link in self for value in link], dtype=float)


# Made up, not measured: the paper gives no masses. An aluminium upper arm and forearm, each
# with its centre of mass about 40 % along it, a light wrist, a handle of 80 g whose centre is
# 30 mm along the roll axis. They hold the shoulder with about 0.5 N*m at home.
SIMULATED_MASSES = LinkMasses(
    link2=(0.15, 0.15 * 0.08, 0.0, 0.0),
    link3=(0.12, 0.12 * 0.06, 0.0, 0.0),
    link4=(0.04, 0.0, 0.0, 0.04 * 0.01),
    link5=(0.03, 0.03 * 0.01, 0.0, 0.0),
    link6=(0.08, 0.0, 0.0, 0.08 * 0.03),
)


def _frames(theta: ArrayLike, arm: str,
            lengths: kinematics.LinkLengths | None) -> tuple[list[Array], list[Array]]:
    """Return each frame's origin and rotation in {0}, frames 1..6."""
    origins, rotations = [], []
    transform = np.eye(4)
    for row in kinematics.dh_table(np.asarray(theta, dtype=float).tolist(), arm, lengths):
        transform = transform @ kinematics.dh_transform(*row)
        origins.append(transform[:3, 3].copy())
        rotations.append(transform[:3, :3].copy())
    return origins, rotations


def standard_regressor(theta: ArrayLike, arm: str = 'right',
                       lengths: kinematics.LinkLengths | None = None) -> Array:
    """
    Return the (5, 20) map from standard parameters to the motors' holding torques.

    The potential energy is U = -g . sum(m_i o_i + R_i (m c)_i); joint j's holding torque is
    dU/dtheta_j = -z_j . (r x g) summed over the links i >= j, r the link's moment arm about
    joint j's origin; the motors' torques follow through the elbow's coupling.
    """
    origins, rotations = _frames(np.asarray(theta, dtype=float), arm, lengths)
    gravity = np.array([0.0, 0.0, -G])
    joint = np.zeros((6, len(STANDARD_NAMES)))
    for j in range(6):
        axis, origin = rotations[j][:, 2], origins[j]
        for k, link in enumerate(LINKS):
            i = link - 1
            if i < j:
                continue
            column = 4 * k
            joint[j, column] = -axis @ np.cross(origins[i] - origin, gravity)
            for direction in range(3):
                joint[j, column + 1 + direction] = -axis @ np.cross(
                    rotations[i][:, direction], gravity)
    return kinematics.actuator_torques(joint.T).T[:kinematics.DRIVEN_JOINTS]


class GravityModel:
    """The base parameters of one arm's kinematics, and the torques they give."""

    def __init__(self, arm: str = 'right', lengths: kinematics.LinkLengths | None = None):
        """Find which combinations of the standard parameters the torques can tell apart."""
        self.arm, self.lengths = arm, lengths
        rng = np.random.default_rng(0)
        lower, upper = kinematics.JOINT_LIMITS[:, 0], kinematics.JOINT_LIMITS[:, 1]
        poses = rng.uniform(lower, upper, size=(_IDENTIFICATION_POSES, 6))
        stacked = np.vstack([standard_regressor(pose, arm, lengths)[:, _MODELLED]
                             for pose in poses])
        stacked /= np.abs(stacked).max()
        chosen: list[int] = []
        for column in range(stacked.shape[1]):
            trial = stacked[:, chosen + [column]]
            if np.linalg.matrix_rank(trial, tol=_RANK_TOLERANCE * len(stacked)) > len(chosen):
                chosen.append(column)
        self._independent = [_MODELLED[c] for c in chosen]
        others = [c for c in range(stacked.shape[1]) if c not in chosen]
        self._dependent = [_MODELLED[c] for c in others]
        # Each dependent column in the independent ones: base = independent + K dependent.
        self._grouping = np.linalg.lstsq(stacked[:, chosen], stacked[:, others], rcond=None)[0]
        self.names = tuple(STANDARD_NAMES[i] for i in self._independent)
        if self.names != BASE_NAMES:
            raise ValueError(f'link lengths {lengths}: the gravity parameters identifiable are '
                             f'{", ".join(self.names)}, not {", ".join(BASE_NAMES)}')

    @property
    def size(self) -> int:
        """Return how many base parameters there are."""
        return len(self._independent)

    def base_parameters(self, masses: LinkMasses) -> Array:
        """Return the base parameters of given standard ones (the simulator's truth)."""
        standard = masses.standard()
        result: Array = standard[self._independent] + self._grouping @ standard[self._dependent]
        return result

    def base_regressor(self, theta: ArrayLike) -> Array:
        """Return the (5, size) map from base parameters to the motors' holding torques."""
        return standard_regressor(theta, self.arm, self.lengths)[:, self._independent]

    def holding_torques(self, theta: ArrayLike, base: ArrayLike) -> Array:
        """Return the five motor torques (N*m) that hold the arm still at `theta`."""
        # The base parameters as standard ones (the dependent ones zero): the same torques,
        # from each link's first moment about {0}, without building the regressor.
        standard = np.zeros(len(STANDARD_NAMES))
        standard[self._independent] = np.asarray(base, dtype=float)
        per_link = standard.reshape(len(LINKS), 4)
        origins, rotations = _frames(np.asarray(theta, dtype=float), self.arm, self.lengths)
        masses = per_link[:, 0]
        moments = [masses[k] * origins[link - 1] + rotations[link - 1] @ per_link[k, 1:]
                   for k, link in enumerate(LINKS)]
        joint = np.zeros(6)
        for j in range(6):
            # The links from j on, about joint j's origin; gravity along -z0.
            outboard = [k for k, link in enumerate(LINKS) if link - 1 >= j]
            moment = sum((moments[k] for k in outboard), np.zeros(3)) - masses[
                outboard].sum() * origins[j]
            axis = rotations[j][:, 2]
            joint[j] = G * (axis[0] * moment[1] - axis[1] * moment[0])
        return kinematics.actuator_torques(joint)[:kinematics.DRIVEN_JOINTS]
