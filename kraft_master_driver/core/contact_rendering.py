# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The master's side of model-mediated teleoperation, no ROS: the arm's contact as a local wall.

ContactRenderer takes each ContactModel (core/contact_model.py) that crosses the delay, in the
master's base frame and its units, and renders it in the driver's loop against the master's
own wrist position and velocity: no delay sits inside the loop the operator closes.

- The wall's stiffness is clipped where the sampled wall stays passive on the device's own
  damping b (Colgate and Schenkel 1997: b > K T / 2 + |B|), its damping to what is left.
- A model update never steps the force. A surface that arrives past the hand is placed where
  the hand is and moved to its place at `approach_speed`; while in contact a new place or
  stiffness is reached the same way, the force changing by at most `approach_speed` times the
  stiffness a second.
- The wall keeps its own books: the work the hand did on it, and what updates put in (at most
  `update_energy` each), against the work it did on the hand. Where pushing the hand would
  take the balance below zero the force fades instead: the wall never generates energy.
  A model sent again unchanged (the arm's side repeats it as a heartbeat) is no update.

Units: m, N, N/m, N*s/m, s; positions and forces in the master's base frame.
"""
from typing import NamedTuple, Optional, Sequence

from kraft_master_driver.core.contact_model import ContactModel

Vector = Sequence[float]
FADE_CYCLES = 20


class RendererSettings(NamedTuple):
    """The wall's limits (SI units)."""

    rate_hz: float = 1000.0  # the loop's rate
    device_damping: float = 0.37  # N*s/m: the simulated device's own, least damped direction
    approach_speed: float = 0.05  # m/s a surface moves to its estimated place
    update_energy: float = 0.05  # J an update may put into the operator's hand
    model_timeout: float = 0.5  # s without a model message: the wall is gone


def renderable_stiffness(rate_hz: float, device_damping: float, damping: float = 0.0) -> float:
    """Return the stiffest passive sampled wall (N/m): K < 2 (b - |B|) / T."""
    return max(0.0, 2.0 * (device_damping - abs(damping)) * rate_hz)


def _dot(a: Vector, b: Vector) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


class ContactRenderer:
    """A virtual plane against the master's wrist: take models, give a force each cycle."""

    def __init__(self, settings: RendererSettings = RendererSettings()) -> None:
        """Start with no wall."""
        self.settings = settings
        self.max_stiffness = renderable_stiffness(settings.rate_hz, settings.device_damping)
        self._model: Optional[ContactModel] = None  # the newest, with its receipt time
        self._received_ns = 0
        self._fresh = False  # a new model to take at the next cycle
        self._normal: Optional[Vector] = None
        self._offset = 0.0  # n . x of the wall rendered now (m)
        self._target = 0.0  # n . x of the model's surface
        self._stiffness = 0.0  # N/m rendered now
        self._damping = 0.0
        self._position: Optional[Vector] = None
        self._force = (0.0, 0.0, 0.0)  # last force given, and the fraction of it applied
        self._applied = 0.0
        self.energy_in = 0.0  # J the hand did on the wall
        self.energy_out = 0.0  # J the wall did on the hand
        self.update_energy_in = 0.0  # J the updates put in
        self.credit = 0.0  # J the newest update may still put in

    def take(self, model: ContactModel, received_ns: int) -> None:
        """Take a model (master base frame and units) received at `received_ns`."""
        previous = self._model
        self._received_ns = received_ns
        if previous is None or previous[:4] != model[:4]:
            self._model, self._fresh = model, True

    @property
    def balance(self) -> float:
        """Return the wall's books (J): the work done on it and the updates' less its own."""
        return self.energy_in + self.update_energy_in - self.energy_out

    def applied(self, fraction: float) -> None:
        """Note the share (0..1) of the last force() that reached the hand."""
        self._applied = fraction

    def force(self, position: Vector, velocity: Vector, now_ns: int) -> tuple[float, ...]:
        """Return the wall's force on the wrist (N, 3) at this cycle's position and velocity."""
        self._book(position)
        model = self._model
        if model is None or now_ns - self._received_ns > self.settings.model_timeout * 1e9:
            return self._gone()
        if self._fresh:
            self._fresh = False
            self._introduce(model, position)
        if self._normal is None:
            return self._gone()
        self._approach(position)
        normal = self._normal
        depth = self._offset - _dot(normal, position)
        if depth <= 0.0:
            self._force = (0.0, 0.0, 0.0)
            return self._force
        magnitude = self._stiffness * depth - self._damping * _dot(normal, velocity)
        magnitude = max(0.0, magnitude) * self._fade(magnitude, normal, velocity)
        self._force = (magnitude * normal[0], magnitude * normal[1], magnitude * normal[2])
        return self._force

    def _book(self, position: Vector) -> None:
        """Book the work of the last force over the motion since (energy in or out)."""
        previous, self._position = self._position, position
        if previous is None:
            return
        fx, fy, fz = self._force
        work = self._applied * (fx * (position[0] - previous[0]) + fy * (
            position[1] - previous[1]) + fz * (position[2] - previous[2]))
        if work > 0.0:
            self.energy_out += work
        else:
            self.energy_in -= work

    def _gone(self) -> tuple[float, ...]:
        self._normal = None
        self._stiffness = 0.0
        self._force = (0.0, 0.0, 0.0)
        return self._force

    def _introduce(self, model: ContactModel, position: Vector) -> None:
        """Take a new model: where it would step the force, start from the force now."""
        if model.stiffness <= 0.0:
            self._gone()
            return
        stiffness = min(model.stiffness, self.max_stiffness)
        damping = min(model.damping, max(0.0, self.settings.device_damping
                                         - stiffness / (2.0 * self.settings.rate_hz)))
        normal = model.normal
        target = _dot(normal, model.point)
        height = _dot(normal, position)
        spring = 0.0 if self._normal is None else self._stiffness * max(
            0.0, self._offset - _dot(self._normal, position))
        # The wall starts where it gives the spring force of now (none: at most at the hand),
        # then approaches its place.
        self._offset = height + spring / stiffness if spring > 0.0 else min(target, height)
        self._normal, self._target = normal, target
        self._stiffness, self._damping = stiffness, damping
        self.credit = self.settings.update_energy

    def _approach(self, position: Vector) -> None:
        """Move the rendered surface toward the model's; outward past the hand only by credit."""
        gap = self._target - self._offset
        if gap == 0.0:
            return
        step = self.settings.approach_speed / self.settings.rate_hz
        move = max(-step, min(step, gap))
        assert self._normal is not None
        depth_after = self._offset + move - _dot(self._normal, position)
        if move > 0.0 and depth_after > 0.0:
            # Moving out into the hand puts energy in: only as far as the credit pays.
            cost = 0.5 * self._stiffness * (depth_after ** 2 - max(
                self._offset - _dot(self._normal, position), 0.0) ** 2)
            if cost > self.credit:
                return
            self.credit -= cost
            self.update_energy_in += cost
        self._offset += move

    def _fade(self, magnitude: float, normal: Vector, velocity: Vector) -> float:
        """Return 1, or less where pushing the hand would take the balance below zero."""
        giving = magnitude * _dot(normal, velocity) / self.settings.rate_hz
        if giving <= 0.0 or self.balance >= giving * FADE_CYCLES:
            return 1.0
        # Faded over the last FADE_CYCLES cycles' worth of work, not cut at once.
        return max(0.0, min(1.0, self.balance / (giving * FADE_CYCLES)))
