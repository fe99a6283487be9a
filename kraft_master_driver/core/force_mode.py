# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Which force the master renders, no ROS: the arm's wrench (direct) or the contact model.

force_mode 'direct' reflects the wrench that crossed the delay (J^T F, with contact damping and
passivity as set), 'model' renders the contact model locally (core/contact_rendering.py), and
'auto' chooses by the measured round trip, with hysteresis: the model above
`model_above` s, direct again below `direct_below` s. The round trip is twice the one-way delay
of the arm's messages (their stamps against the receipt; the clocks of the two sides must
agree, as for max_wrench_age), held at its peak and decaying over `ROUND_TRIP_MEMORY` s, so one
fast message does not switch back. A switch blends the two forces over `switch_time` s: no
step at the hand. With passivity on, 'auto' renders the model at every round trip.
"""
from collections.abc import Sequence
from enum import StrEnum
import math
from typing import NamedTuple

from kraft_master_driver.core.contact_model import ContactModel
from kraft_master_driver.core.contact_rendering import ContactRenderer


class ForceMode(StrEnum):
    """The force_mode parameter's values."""

    AUTO = 'auto'
    DIRECT = 'direct'
    MODEL = 'model'


ROUND_TRIP_MEMORY = 2.0  # s


class ModeSettings(NamedTuple):
    """The choice's thresholds (s)."""

    mode: ForceMode = ForceMode.DIRECT
    model_above: float = 0.05
    direct_below: float = 0.03
    switch_time: float = 0.1


class ModeSelector:
    """The share of the model in the force (0: direct, 1: model), from the measured delay."""

    def __init__(self, settings: ModeSettings = ModeSettings(), passivity: bool = False) -> None:
        """
        Start direct, unless force_mode is 'model', or 'auto' with passivity on.

        passivity (settable later): with it on, 'auto' renders the model at every round trip,
        as its wall keeps its own books where the direct force through the passivity port is
        numb.
        """
        if not 0.0 <= settings.direct_below <= settings.model_above:
            raise ValueError(f'direct_below: {settings.direct_below:g} s must be within 0 .. '
                             f'model_above {settings.model_above:g} s')
        self.settings = settings
        self.passivity = passivity
        self.round_trip = 0.0  # s, the estimate
        self._round_trip_at = 0
        self.model_chosen = settings.mode is ForceMode.MODEL or (
            settings.mode is ForceMode.AUTO and passivity)
        self._weight = 1.0 if self.model_chosen else 0.0
        self._weight_at = 0

    def delay(self, one_way: float, now_ns: int) -> None:
        """Note how long (s) one message from the arm's side took to come, received at `now_ns`."""
        elapsed = max(0, now_ns - self._round_trip_at) / 1e9
        decayed = self.round_trip * math.exp(-elapsed / ROUND_TRIP_MEMORY)
        self.round_trip, self._round_trip_at = max(2.0 * one_way, decayed), now_ns
        settings = self.settings
        if settings.mode is not ForceMode.AUTO:
            return
        if self.passivity:
            self.model_chosen = True
        elif not self.model_chosen and self.round_trip > settings.model_above:
            self.model_chosen = True
        elif self.model_chosen and self.round_trip < settings.direct_below:
            self.model_chosen = False

    def weight(self, now_ns: int) -> float:
        """Return the model's share of the force now, ramped toward the choice."""
        elapsed = max(0, now_ns - self._weight_at) / 1e9
        self._weight_at = now_ns
        step = elapsed / self.settings.switch_time if self.settings.switch_time > 0 else 1.0
        goal = 1.0 if self.model_chosen else 0.0
        self._weight = goal if abs(goal - self._weight) <= step else (
            self._weight + math.copysign(step, goal - self._weight))
        return self._weight


class ModelFeedback:
    """
    The driver's side of the contact model: what comes in, and the model's force each cycle.

    The loop thread hands it each contact model and each message's delay (take, delay), asks
    it for the model's force and share before each send (force) and tells it what reached the
    hand (applied). A model that is not fresh renders nothing (core/contact_rendering.py).
    """

    def __init__(self, selector: ModeSelector, renderer: ContactRenderer) -> None:
        """Take the choice of mode and the wall."""
        self.selector = selector
        self.renderer = renderer
        self.share = 0.0

    def take(self, model: ContactModel, received_ns: int) -> None:
        """Take a contact model (master base frame and units) received at `received_ns`."""
        self.renderer.take(model, received_ns)

    def delay(self, one_way: float, now_ns: int) -> None:
        """Note how long (s) one message from the arm's side took to come."""
        self.selector.delay(one_way, now_ns)

    def force(self, position: Sequence[float], velocity: Sequence[float],
              now_ns: int) -> tuple[Sequence[float], float]:
        """Return the wall's force on the wrist (N, 3, base frame) and the model's share (0..1)."""
        self.share = self.selector.weight(now_ns)
        return self.renderer.force(position, velocity, now_ns), self.share

    def applied(self, share: float) -> None:
        """Note the model's share of the force this cycle's torques carried (0: none)."""
        self.renderer.applied(share)

    def idle(self) -> None:
        """Note a cycle without a pot frame: the wall's books see no motion and no force."""
        self.renderer.applied(0.0)
