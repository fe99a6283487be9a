# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The bridge's contact model, no ROS: estimate what the arm touches, tell the master, yield.

ContactSharing feeds the ContactEstimator (core/contact_model.py) with each F/T reading's
contact force and the arm's measured position, and says what to send on `contact_model`: the
model in the master's frame and units (through the registration, base_rotation and scale; the
stiffness of the arm's impedance, arm_stiffness, in series with the estimated contact's, times
scale and force_scale), when it changed by more than the dead band or `HEARTBEAT` s passed; a
model of stiffness 0 while the arm does not follow, so the master renders no wall then.

Where the arm presses harder than the model the master was last sent, by more than
model_tolerance, the arm yields: its target goes no deeper along the normal until the force is
back within half the tolerance (Motion.floor), while the model is corrected. model_tolerance 0
(the default) leaves the yielding to the arm's impedance: an impact's force is far above any
quasi-static model, and with direct force the master never renders the model.
"""
import math
from typing import NamedTuple, Optional

from kraft_master_driver.core.contact_model import (
    ContactEstimator, ContactModel, EstimatorSettings, NO_CONTACT)
from kraft_master_driver.core.teleoperation_motion import Pose
from kraft_master_driver.core.teleoperation_settings import Array, Settings
import numpy as np

HEARTBEAT = 0.1  # s between models sent unchanged
DEAD_BAND_POSITION = 0.0005  # m of the surface's place along its normal
DEAD_BAND_ANGLE = math.radians(2.0)
DEAD_BAND_STIFFNESS = 0.1  # of the stiffness


class Registration(NamedTuple):
    """The master's pose and the arm's that map onto each other, and the base rotation."""

    master: Pose
    arm: Pose
    base_rotation: Array


def _series(contact: float, arm: float) -> float:
    return contact * arm / (contact + arm) if arm > 0.0 else contact


def _changed(sent: ContactModel, model: ContactModel) -> bool:
    """Whether `model` differs from `sent` by more than the dead band."""
    if (sent.stiffness > 0.0) != (model.stiffness > 0.0) or sent.in_contact != model.in_contact:
        return True
    if model.stiffness <= 0.0:
        return False
    cosine = float(np.dot(sent.normal, model.normal))
    offset = float(np.dot(model.normal, np.subtract(model.point, sent.point)))
    return (math.acos(min(1.0, cosine)) > DEAD_BAND_ANGLE
            or abs(offset) > DEAD_BAND_POSITION
            or abs(model.stiffness - sent.stiffness) > DEAD_BAND_STIFFNESS * sent.stiffness)


class ContactSharing:
    """The contact estimate of one bridge: readings in, models for the master and a floor out."""

    def __init__(self, settings: Settings, estimator: EstimatorSettings = EstimatorSettings()
                 ) -> None:
        """Take the bridge's settings."""
        self.settings = settings
        self.estimator = ContactEstimator(estimator)
        self._sent: Optional[ContactModel] = None  # in the master's frame
        self._sent_at = -math.inf
        self._known = NO_CONTACT  # the arm-frame model the master was last sent
        self.floor: Optional[tuple[Array, float]] = None  # normal (arm) and least n . x

    def reading(self, position: Array, force: Array, command: Optional[Pose],
                now: float) -> Optional[tuple[Array, float]]:
        """
        Take the arm's position, the contact force (arm base) and its command (None: none).

        Return the floor (Motion.floor): where the arm yields, or None.
        """
        self.estimator.update(position, force, now)
        known = self._known
        tolerance = self.settings.model_tolerance
        if known.stiffness <= 0.0 or tolerance <= 0.0:
            self.floor = None
            return None
        normal = np.array(known.normal)
        pressing = float(normal @ force)
        expected = known.stiffness * max(float(normal @ (np.array(known.point) - position)), 0.0)
        excess = pressing - expected
        if command is not None and excess > tolerance:
            if self.floor is None:
                self.floor = (normal, float(normal @ command.position))
        elif excess < 0.5 * tolerance:
            self.floor = None
        return self.floor

    def to_send(self, registration: Optional[Registration], now: float
                ) -> Optional[ContactModel]:
        """Return the model to send now (master frame), or None: nothing new to send."""
        model = NO_CONTACT if registration is None else self._in_master(registration)
        sent = self._sent
        if sent is not None and not _changed(sent, model) and now - self._sent_at < HEARTBEAT:
            return None
        self._sent, self._sent_at = model, now
        if registration is None:
            self._known = NO_CONTACT
        elif sent is None or _changed(sent, model):
            self._known = self.estimator.model()
        return model

    def _in_master(self, registration: Registration) -> ContactModel:
        """Return the estimate in the master's frame and units."""
        model = self.estimator.model()
        if model.stiffness <= 0.0:
            return NO_CONTACT
        settings = self.settings
        back = registration.base_rotation.T
        point = registration.master.position + back @ (
            np.array(model.point) - registration.arm.position) / settings.scale
        gain = settings.force_scale * settings.scale
        stiffness = gain * _series(model.stiffness, settings.arm_stiffness)
        return ContactModel(tuple(point.tolist()), tuple((back @ model.normal).tolist()),
                            stiffness, gain * model.damping, model.confidence,
                            model.in_contact)
