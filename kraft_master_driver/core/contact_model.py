# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The arm's side of model-mediated teleoperation, no ROS: a contact model estimated online.

ContactEstimator takes the arm's measured tool position and the contact force (the
environment's force on the tool, arm base frame) at each F/T reading and estimates a plane (a
point and the normal, out of the surface), the stiffness and damping along the normal, a
confidence and whether the arm touches now. The normal is the direction of the contact force
(a frictionless plane), the plane's place where the arm was at the last reading before the
touch, and the stiffness and damping come from recursive least squares with forgetting on
f = k p + b dp/dt, p the depth past the plane, restarted at each new touch from the last
stiffness and damping, so a table that moved between touches is found again. Free motion past
the model's surface (no force where the model says there is one) moves the surface beyond the
arm at once.

Shapes it does not cover: edges, corners and curved surfaces (one plane only); a surface the
tool slides along with friction (the normal tilts by the friction angle); contacts whose
force depends on more than the depth and its rate (Hunt-Crossley, plastic, moving objects).

ContactModel is what crosses the delay; MODEL_FIELDS is its layout on the wire
(doc/ros-interface.md, `contact_model`).
"""
import math
from typing import NamedTuple, Optional, Sequence

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

MODEL_FIELDS = ('point_x', 'point_y', 'point_z', 'normal_x', 'normal_y', 'normal_z',
                'stiffness', 'damping', 'confidence', 'in_contact')


class ContactModel(NamedTuple):
    """A plane contact: point (m), unit normal out of it, N/m, N*s/m, confidence 0..1."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    stiffness: float
    damping: float
    confidence: float
    in_contact: bool

    def values(self) -> list[float]:
        """Return the model as the floats of MODEL_FIELDS, in order."""
        return [*self.point, *self.normal, self.stiffness, self.damping, self.confidence,
                float(self.in_contact)]

    @classmethod
    def from_values(cls, names: Sequence[str], values: Sequence[float]) -> 'ContactModel':
        """Return the model of named values (ValueError in one line if they cannot be one)."""
        if tuple(names) != MODEL_FIELDS or len(values) != len(MODEL_FIELDS):
            raise ValueError(f'contact_model: expected the fields {", ".join(MODEL_FIELDS)}, '
                             f'got {len(values)} values named {list(names)}')
        if not all(math.isfinite(value) for value in values):
            raise ValueError('contact_model: a value is not finite')
        normal = values[3:6]
        length = math.sqrt(sum(x * x for x in normal))
        stiffness, damping, confidence = values[6:9]
        if stiffness > 0.0 and abs(length - 1.0) > 1e-3:
            raise ValueError(f'contact_model: the normal is {length:g} long, not 1')
        if stiffness < 0.0 or damping < 0.0 or not 0.0 <= confidence <= 1.0:
            raise ValueError('contact_model: stiffness and damping must be >= 0 and the '
                             'confidence in 0..1')
        px, py, pz = values[0:3]
        nx, ny, nz = normal
        return cls((px, py, pz), (nx, ny, nz), stiffness, damping, confidence, values[9] >= 0.5)


NO_CONTACT = ContactModel((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0.0, 0.0, 0.0, False)


class EstimatorSettings(NamedTuple):
    """How the contact is found and fitted (SI units)."""

    contact_force: float = 1.0  # N: a touch begins at this force
    release_force: float = 0.5  # N: and ends below this one
    forgetting: float = 0.995  # per reading: at 500 Hz, a memory of about 0.4 s
    stiffness_guess: float = 2000.0  # N/m: the first touch's prior
    damping_guess: float = 0.0  # N*s/m
    min_stiffness: float = 100.0  # N/m: below this the fit is not a contact
    free_depth: float = 0.001  # m past the surface without force: the surface is not there
    still_speed: float = 0.02  # m/s: slower than this, the force's direction is the normal's


# Prior variances of the fit (stiffness, damping) at a new touch.
_PRIOR = (1e6, 1e4)
_TRACE_CAP = 1e8  # keeps forgetting from winding the covariance up while the data say nothing
SAME_SURFACE = math.cos(math.radians(45.0))  # a touch this near the normal: the same surface


class ContactEstimator:
    """The plane, stiffness and damping of what the arm touches, from pose and force."""

    def __init__(self, settings: EstimatorSettings = EstimatorSettings()) -> None:
        """Start with no contact seen."""
        self.settings = settings
        self.in_contact = False
        self._normal: Optional[Array] = None
        self._offset = 0.0  # n . x on the surface (m)
        self._stiffness = settings.stiffness_guess
        self._damping = settings.damping_guess
        self._surface = np.zeros(3)  # where the arm was just before this touch (m)
        self._force_sum = np.zeros(3)  # N, the forces on this surface: the normal
        self._theta = np.zeros(2)  # stiffness, damping
        self._covariance = np.diag(_PRIOR)
        self._residual = 0.0  # N^2, forgetting mean of the squared residual
        self._samples = 0
        self._previous: Optional[tuple[Array, float]] = None

    def model(self) -> ContactModel:
        """Return the model now (NO_CONTACT before the first touch)."""
        if self._normal is None:
            return NO_CONTACT
        normal = self._normal
        point = self._surface
        spread = math.sqrt(max(self._covariance[0, 0], 0.0) * max(self._residual, 1e-6))
        confidence = (self._samples / (self._samples + 20.0)) * max(
            0.0, 1.0 - spread / self._stiffness)
        px, py, pz = point.tolist()
        nx, ny, nz = normal.tolist()
        return ContactModel((px, py, pz), (nx, ny, nz), self._stiffness,
                            self._damping, confidence, self.in_contact)

    def predicted_force(self, position: Array) -> float:
        """Return the force along the normal (N) the model gives at `position`, 0 off it."""
        if self._normal is None:
            return 0.0
        return max(0.0, self._stiffness * (self._offset - float(self._normal @ position)))

    def update(self, position: Array, force: Array, now: float) -> None:
        """Take one reading: tool position (m), contact force on the tool (N), time (s)."""
        settings = self.settings
        previous, self._previous = self._previous, (position, now)
        magnitude = float(np.linalg.norm(force))
        threshold = settings.release_force if self.in_contact else settings.contact_force
        touching = magnitude >= threshold
        if touching and not self.in_contact:
            before = position if previous is None else previous[0]
            self._begin_touch(before, force / magnitude)
        self.in_contact = touching
        if not touching:
            if previous is not None:
                self._check_free(position, previous[0])
            return
        if previous is None or now <= previous[1]:
            return
        velocity = (position - previous[0]) / (now - previous[1])
        if float(np.linalg.norm(velocity)) < settings.still_speed:
            # The normal is the mean direction of the forces while the arm is nearly still,
            # over every touch of this surface: impacts and sliding friction tilt the force.
            self._force_sum = self._force_sum + force
            self._normal = self._force_sum / np.linalg.norm(self._force_sum)
        normal = self._normal
        assert normal is not None  # the touch began with one
        depth = float(normal @ (self._surface - position))
        rate = float(normal @ velocity)
        self._offset = float(normal @ self._surface)
        self._fit(np.array([depth, -rate]), float(normal @ force))

    def _begin_touch(self, position: Array, direction: Array) -> None:
        """Begin a touch: the plane through here, the fit restarted from the last k and b."""
        if self._normal is None or float(self._normal @ direction) < SAME_SURFACE:
            self._force_sum = np.zeros(3)
            self._normal = direction
        self._surface = position
        self._offset = float(direction @ position)
        self._theta = np.array([self._stiffness, self._damping])
        self._covariance = np.diag(_PRIOR)
        self._samples = 0

    def _fit(self, regressor: Array, force: float) -> None:
        """One step of recursive least squares with forgetting; keep what is physical."""
        settings = self.settings
        covariance = self._covariance
        gain_direction = covariance @ regressor
        error = force - float(regressor @ self._theta)
        gain = gain_direction / (settings.forgetting + float(regressor @ gain_direction))
        self._theta = self._theta + gain * error
        covariance = (covariance - np.outer(gain, gain_direction)) / settings.forgetting
        if np.trace(covariance) > _TRACE_CAP:
            covariance *= _TRACE_CAP / np.trace(covariance)
        self._covariance = covariance
        self._residual = settings.forgetting * self._residual + (1 - settings.forgetting) * (
            error * error)
        self._samples += 1
        stiffness, damping = self._theta
        if stiffness >= settings.min_stiffness:
            self._stiffness = float(stiffness)
            self._damping = max(0.0, float(damping))

    def _check_free(self, position: Array, before: Array) -> None:
        """
        Without force past the surface, the surface is not there: move it past the arm.

        Not while the arm moves out of it: a surface that springs back slower than the arm
        leaves (a table top on its spring) is still there.
        """
        if self._normal is None:
            return
        height = float(self._normal @ position)
        leaving = height > float(self._normal @ before)
        if not leaving and height < self._offset - self.settings.free_depth:
            self._offset = height
            self._surface = position
