# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The torque limits of force reflection (core/force_reflection.py), the arm's weight inside them.

Pure logic, no ROS, driven by the loop thread alone: limit() once per cycle that sends torque,
reset() at every zero-torque cycle.
"""
from collections.abc import Sequence
import math
from typing import NamedTuple


class Limited(NamedTuple):
    """Torques inside the limits (N*m, actuator axes 1..5), before the force ramp."""

    torques: list[float]
    factor: float  # the share of the reflected torques kept (0..1)
    saturated: bool  # scaled down, or the weight clamped


class TorqueLimiter:
    """Keeps the reflected torques plus the weight inside the limits; counts what it did."""

    def __init__(self) -> None:
        """Start unsaturated, every counter zero."""
        self._was_saturated = False
        self.saturation_events = 0
        self.saturated_cycles = 0
        self.non_finite_results = 0

    def reset(self) -> None:
        """Note a cycle that sent zero torque: the next saturation is a new event."""
        self._was_saturated = False

    def limit(self, torques: Sequence[float], holding: Sequence[float] | None,
              limits: Sequence[float], actuator_form: bool) -> Limited | None:
        """
        Add the holding torques and keep the sum inside `limits`; None if any is not finite.

        The reflected torques are scaled down as one vector (keeping the force's direction) so
        that, with the arm's weight added, no axis passes its limit; the weight itself is only
        clamped, each axis on its own.
        """
        weight, clamped = (0.0,) * len(limits), False
        if holding is not None:
            h1, h2, h3, h4, h5 = holding
            # Actuator axes; a device taking joint torques gets tau2 = tau_q2 + tau_q3.
            wanted = (h1, h2 if actuator_form else h2 + h3, h3, h4, h5)
            weight = tuple(min(max(h, -limit), limit) for h, limit in zip(wanted, limits))
            clamped = weight != wanted
        if not all(map(math.isfinite, (*torques, *weight))):
            self.non_finite_results += 1
            return None
        # The largest share of the reflected torques that each axis's headroom allows.
        factor = min([1.0] + [(limit - math.copysign(w, tau)) / abs(tau)
                              for tau, w, limit in zip(torques, weight, limits)
                              if abs(tau + w) > limit])
        saturated = factor < 1.0 or clamped
        if saturated:
            self.saturated_cycles += 1
            if not self._was_saturated:
                self.saturation_events += 1
        self._was_saturated = saturated
        # The clamp only trims rounding.
        return Limited([min(max(tau * factor + w, -limit), limit)
                        for tau, w, limit in zip(torques, weight, limits)], factor, saturated)
