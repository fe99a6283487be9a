# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The teleoperation bridge's motion path, no ROS: master pose -> the arm's command.

From the registration on, the master's motion is mapped into the arm's base frame (scale,
base_rotation, orientation), kept in the workspace box, moved toward within the speed limits,
and passed through passivity's slave port; twist mode drives the arm toward that command.
"""
from typing import NamedTuple, Optional

from kraft_master_driver.core.passivity import SlavePort
from kraft_master_driver.core.rotations import (
    clamp_norm, rotation_from_vector, rotation_to_quaternion, rotation_vector)
from kraft_master_driver.core.teleoperation_settings import Array, Settings
import numpy as np


class Pose(NamedTuple):
    """A position (m, 3) and a rotation matrix (3x3), in one base frame."""

    position: Array
    rotation: Array

    @property
    def quaternion(self) -> tuple[float, float, float, float]:
        """Return the orientation: the unit quaternion x, y, z, w."""
        return rotation_to_quaternion(self.rotation)


class Motion:
    """The arm's command: following, mapped, boxed, speed-limited, through the port; or held."""

    def __init__(self, settings: Settings, box: tuple[Array, Array], port: SlavePort) -> None:
        """Take the settings, the workspace box (lower, upper corner) and the slave port."""
        self.settings = settings
        self.box = box
        self.port = port
        self.registration: Optional[tuple[Pose, Pose]] = None  # (master, arm) poses
        self.command: Optional[Pose] = None  # the last pose commanded while following
        self._target: Optional[Pose] = None  # the speed-limited target, before the port
        # Where the arm yields: a normal (arm base) and the least n . x of the target.
        self.floor: Optional[tuple[Array, float]] = None
        self.hold: Optional[Pose] = None  # the pose the arm holds while not following
        # Held because the arm's side was late: it follows again from where it is measured.
        self.held_for_arm = False

    def hold_here(self, for_arm: bool = False) -> None:
        """Stop following: hold at the last command (or the hold, if none was commanded)."""
        self.hold = self.command or self.hold
        self.registration = None
        self.held_for_arm = for_arm

    def hold_at_fault(self, arm: Optional[tuple[Pose, float]], now: float) -> None:
        """Stop following: hold where measured, if younger than arm_hold_timeout, else sent."""
        fresh = arm is not None and now - arm[1] <= self.settings.arm_hold_timeout
        self.hold_here()
        if fresh:
            assert arm is not None
            self.hold = arm[0]

    def follow_again(self, master: Pose, measured: Pose) -> None:
        """
        Register the master's pose anew at the hold.

        An arm held for its own side (stalled, restarted) is where it is measured, not where it
        was sent: from there, not dragged back.
        """
        if self.held_for_arm:
            self.hold, self.held_for_arm = measured, False
        assert self.hold is not None  # enable, the clutch and a stale pose set it
        self.register(master, self.hold)

    def register(self, master: Pose, held: Pose) -> None:
        """Take the offset anew: the master's pose `master` maps to the arm's `held`."""
        self.registration = (master, held)
        self._target = held
        self.command = held
        self.port.reset(held.position.tolist())

    def _mapped(self, pose: Pose, base_rotation: Array) -> Pose:
        """Return the arm target of a master pose through the registration."""
        assert self.registration is not None
        master0, arm0 = self.registration
        position = arm0.position + self.settings.scale * (
            base_rotation @ (pose.position - master0.position))
        if self.settings.orientation == 'follow':
            turn = base_rotation @ pose.rotation @ master0.rotation.T @ base_rotation.T
            orientation = turn @ arm0.rotation
        else:
            orientation = arm0.rotation
        return Pose(np.clip(position, *self.box), orientation)

    def follow(self, pose: Pose, dt: float, base_rotation: Array, force: Array) -> None:
        """Move the target toward the mapped master pose within the speed limits, `dt` s on."""
        assert self._target is not None
        wanted = self._mapped(pose, base_rotation)
        if self.floor is not None:
            normal, least = self.floor
            below = least - float(normal @ wanted.position)
            if below > 0.0:
                wanted = Pose(wanted.position + below * normal, wanted.rotation)
        settings, target = self.settings, self._target
        step = clamp_norm(wanted.position - target.position, settings.max_linear_speed * dt)
        turn = clamp_norm(rotation_vector(wanted.rotation @ target.rotation.T),
                          settings.max_angular_speed * dt)
        self._target = target = Pose(target.position + step,
                                     rotation_from_vector(turn) @ target.rotation)
        position = self.port.step(target.position.tolist(), force.tolist(), dt)
        self.command = Pose(np.array(position), target.rotation)

    def twist(self, measured: Pose) -> Array:
        """Return the twist toward the command from `measured` (6: m/s, rad/s, arm base)."""
        assert self.command is not None
        settings, command = self.settings, self.command
        linear = clamp_norm(settings.twist_gain * (command.position - measured.position),
                            settings.max_linear_speed)
        angular = np.zeros(3)
        if settings.orientation != 'ignore':
            angular = clamp_norm(settings.twist_gain * rotation_vector(
                command.rotation @ measured.rotation.T), settings.max_angular_speed)
        return np.concatenate([linear, angular])
