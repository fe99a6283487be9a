# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The package's one rule for paced cycles and late ones, without ROS.

A Pacer keeps a grid of deadlines a period apart. advance() moves to the next deadline. A cycle
whose deadline has already passed when it gets there (a late wake-up: the thread was
descheduled, or the cycle before overran) runs at once, and the whole periods that passed
meanwhile are skipped, not run: the deadline moves to the last one of the grid at or before
now, so the grid keeps its phase and a late thread never runs a burst of cycles to catch up.
advance() returns how many periods were skipped, for the caller to count (the driver's loop)
or to replay its own way (the MuJoCo arm steps its physics for each, up to a cap).

    pacer = Pacer(1_000_000)          # 1 ms
    pacer.restart()                   # the first deadline: now
    while running:
        missed = pacer.advance()
        if missed is None:            # on time
            pacer.sleep()
        cycle(missed or 0)

The driver's control loop (core.control_loop) and every paced thread of the nodes
(nodes.ros_io.run_paced) follow this rule.
"""
import time
from typing import Protocol


class Clock(Protocol):
    """What a Pacer reads and waits on: monotonic time in ns, and a sleep in seconds."""

    def monotonic_ns(self) -> int:
        """Return monotonic time (ns)."""

    def sleep(self, seconds: float) -> None:
        """Wait `seconds`."""


class MonotonicClock:
    """The system's monotonic clock and sleep."""

    monotonic_ns = staticmethod(time.monotonic_ns)
    sleep = staticmethod(time.sleep)


class Pacer:
    """
    A deadline grid with a period: the next deadline, waiting for it, and late wake-ups.

    period_ns: the grid's period. deadline_ns: the deadline of the cycle under way. now_ns:
    the time advance() read last.
    """

    __slots__ = ('period_ns', 'clock', 'deadline_ns', 'now_ns')

    def __init__(self, period_ns: int, clock: Clock = MonotonicClock()) -> None:
        """Pace cycles `period_ns` apart on `clock`; restart() sets the grid's phase first."""
        if period_ns <= 0:
            raise ValueError(f'period must be positive, got {period_ns} ns')
        self.period_ns = period_ns
        self.clock = clock
        self.deadline_ns = self.now_ns = 0

    def restart(self) -> int:
        """Put the grid's phase at now, the deadline of the cycle under way; return now."""
        self.deadline_ns = now = self.clock.monotonic_ns()
        return now

    def advance(self) -> int | None:
        """
        Move to the next deadline; return None if it is still ahead, else the periods missed.

        Late (the deadline has passed): the cycle is due at once, and the whole periods that
        passed since the deadline are skipped, the deadline moving over them on the grid.
        """
        self.deadline_ns += self.period_ns
        self.now_ns = now = self.clock.monotonic_ns()
        if now < self.deadline_ns:
            return None
        missed = (now - self.deadline_ns) // self.period_ns
        self.deadline_ns += missed * self.period_ns
        return missed

    def seconds_left(self) -> float:
        """Return the seconds until the deadline: 0 or less once it is due."""
        return (self.deadline_ns - self.clock.monotonic_ns()) / 1e9

    def sleep(self) -> int:
        """Sleep until the deadline (not at all if it has passed); return the time after."""
        clock = self.clock
        clock.sleep(max(0, self.deadline_ns - clock.monotonic_ns()) / 1e9)
        return clock.monotonic_ns()
