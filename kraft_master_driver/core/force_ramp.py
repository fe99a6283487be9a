# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The ramp of the force coming back after torques were zeroed (core/force_reflection.py).

Pure logic, no ROS, driven by the loop thread alone: restart() at every zero-torque cycle,
step() once per cycle, whose share (0..1) scales the torques sent.
"""

# A late cycle advances the ramp by at most this share of it.
RAMP_STEP_LIMIT = 0.1
# The simulated KMC's command watchdog (simulation/master/electronics.py): after a longer gap
# between cycles the device may have zeroed its torques. A shorter gap zeroes nothing there,
# so restarting the ramp on it would itself drop the force, the arm's weight included.
DEVICE_WATCHDOG_NS = 100_000_000


class ForceRamp:
    """The share of the force given: zero after an interruption, then up over the ramp's time."""

    def __init__(self) -> None:
        """Start at zero, before any cycle."""
        self.share = 0.0
        self._ramped_ns = 0
        self._last_cycle_ns: int | None = None

    def restart(self) -> None:
        """Start again from zero: the torques were zeroed this cycle."""
        self._ramped_ns = 0

    def step(self, now_ns: int, ramp_ns: int) -> float:
        """
        Advance by the time since the last cycle, at most RAMP_STEP_LIMIT of ramp_ns.

        A gap longer than DEVICE_WATCHDOG_NS since the last cycle starts it again from zero.
        ramp_ns 0: no ramp. Return the share.
        """
        last, self._last_cycle_ns = self._last_cycle_ns, now_ns
        if last is None or now_ns - last > DEVICE_WATCHDOG_NS:
            self._ramped_ns = 0
        elif self._ramped_ns < ramp_ns:
            self._ramped_ns += min(max(now_ns - last, 0), round(RAMP_STEP_LIMIT * ramp_ns))
        self.share = min(1.0, self._ramped_ns / ramp_ns) if ramp_ns else 1.0
        return self.share


class ShareSlew:
    """
    The contact model's share of the force (0..1), moving toward its goal over the ramp's time.

    When the direct wrench goes stale the model takes the whole force, and gives it back when a
    wrench comes again: without the slew, the model's force would step in (or out) at once.
    """

    def __init__(self) -> None:
        """Start at no share; the first step takes its goal at once."""
        self.share = 0.0
        self._last_cycle_ns: int | None = None

    def step(self, goal: float, now_ns: int, ramp_ns: int) -> float:
        """
        Move toward `goal` by the time since the last cycle over ramp_ns, and return the share.

        As for the ramp, a late cycle moves it by at most RAMP_STEP_LIMIT; ramp_ns 0: at once.
        """
        last, self._last_cycle_ns = self._last_cycle_ns, now_ns
        if last is None or not ramp_ns:
            self.share = goal
            return goal
        step = min(max(now_ns - last, 0) / ramp_ns, RAMP_STEP_LIMIT)
        gap = goal - self.share
        self.share = goal if abs(gap) <= step else self.share + (step if gap > 0 else -step)
        return self.share
