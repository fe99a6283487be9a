# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The joint velocity of the driver's loop, no ROS: finite differences through a low-pass."""
from collections.abc import Sequence
import math


class VelocityFilter:
    """Joint velocity: finite differences through a first-order low-pass filter, in floats."""

    def __init__(self, cutoff_hz: float, size: int = 6) -> None:
        """Filter with the given cut-off frequency."""
        self.cutoff_hz = cutoff_hz
        self.size = size
        self.value = [0.0] * size
        self._last: tuple[float, ...] | None = None
        self._last_ns = 0

    def update(self, position: Sequence[float], time_ns: int) -> list[float]:
        """Take a sample (rad, `size` floats; time in ns); return the velocity (list, rad/s)."""
        if self._last is not None and time_ns > self._last_ns:
            dt = (time_ns - self._last_ns) / 1e9
            alpha = 1.0 - math.exp(-2.0 * math.pi * self.cutoff_hz * dt)
            self.value = [v + alpha * ((now - before) / dt - v)
                          for v, now, before in zip(self.value, position, self._last)]
        self._last = tuple(position)
        self._last_ns = time_ns
        return self.value

    def reset(self) -> None:
        """Forget the history (after a link fault): the next sample starts from rest."""
        self.value = [0.0] * self.size
        self._last = None
