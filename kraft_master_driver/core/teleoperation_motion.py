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


# The arm is taken as still, so that a measured pose a little late is still where it is, once
# it has stayed this near one pose for SETTLE_TIME of its own clock: under 10 mm/s, 0.1 rad/s.
SETTLE_TIME = 0.05  # s, of the measured poses' stamps
SETTLE_DISTANCE = 0.0005  # m
SETTLE_ANGLE = 0.005  # rad


class Settling:
    """
    Whether the arm is still: its measured poses near one pose for SETTLE_TIME of their stamps.

    Told each measured pose with its stamp (the arm's clock: its differences alone count). A
    gap in the stamps longer than the bridge's arm_hold_timeout, or one going back, starts the
    count again: what the arm did in between is not known. A pose stamped as the one before
    counts only if near.
    """

    def __init__(self) -> None:
        """Start not knowing: not still."""
        self._since: Optional[tuple[Pose, float]] = None  # the pose it stays near, and since
        self._last_stamp: Optional[float] = None

    def measured(self, pose: Pose, stamp: float, longest_gap: float) -> None:
        """Take one measured pose, stamped `stamp` (s); after `longest_gap` s, start again."""
        gap = None if self._last_stamp is None else stamp - self._last_stamp
        self._last_stamp = stamp
        if (self._since is None or gap is None or not 0.0 <= gap <= longest_gap
                or _apart(pose, self._since[0])):
            self._since = (pose, stamp)

    def restart(self) -> None:
        """Forget the poses so far: what the arm did since the last one is not known."""
        self._since = None

    @property
    def still(self) -> bool:
        """Return whether the arm has stayed near one pose for SETTLE_TIME."""
        return (self._since is not None and self._last_stamp is not None
                and self._last_stamp - self._since[1] >= SETTLE_TIME)


def _apart(pose: Pose, other: Pose) -> bool:
    """Return whether two poses are farther apart than SETTLE_DISTANCE or SETTLE_ANGLE."""
    turn = rotation_vector(pose.rotation @ other.rotation.T)
    return bool(np.linalg.norm(pose.position - other.position) > SETTLE_DISTANCE
                or np.linalg.norm(turn) > SETTLE_ANGLE)


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
