# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Cheap per-cycle bookkeeping for the control loop: period and CPU statistics."""
import numpy as np
from numpy.typing import NDArray


class RecentSamples:
    """The last `size` samples of one quantity (ns) in a ring buffer, for percentiles."""

    def __init__(self, size: int = 4096) -> None:
        """Keep the last `size` samples."""
        self.samples_ns = np.zeros(size, dtype=np.int64)
        self.count = 0

    def add(self, value_ns: int) -> None:
        """Record one sample."""
        self.samples_ns[self.count % self.samples_ns.size] = value_ns
        self.count += 1

    def recent(self) -> NDArray[np.int64]:
        """Return the samples held (ns), in ring order."""
        return self.samples_ns[:min(self.count, self.samples_ns.size)]

    def percentiles_s(self) -> tuple[float, float, float]:
        """Return (median, p99, max) of the samples held, in seconds (zeros when empty)."""
        samples = self.recent()
        if samples.size == 0:
            return 0.0, 0.0, 0.0
        median, p99 = np.percentile(samples, (50, 99)) / 1e9
        return float(median), float(p99), float(samples.max()) / 1e9


class LoopStatistics:
    """Cycle periods and link round trips in ring buffers, and counters for diagnostics."""

    def __init__(self, window: int = 4096) -> None:
        """Keep the last `window` periods and round trips."""
        self.periods = RecentSamples(window)
        self.round_trips = RecentSamples(window)
        self.frames = 0
        self.published = 0
        self.late = 0
        self.missed = 0
        self.internal_errors = 0
        self.cpu_ns = {'link': 0, 'kinematics': 0, 'publish': 0}
        self._last_start_ns: int | None = None

    @property
    def cycles(self) -> int:
        """Cycles started since the first one."""
        return self.periods.count

    def record_start(self, start_ns: int) -> None:
        """Note the start of a cycle (time.monotonic_ns())."""
        if self._last_start_ns is not None:
            self.periods.add(start_ns - self._last_start_ns)
        self._last_start_ns = start_ns

    def add_cpu(self, **phases: int) -> None:
        """Add thread CPU time (ns) spent in phases link, kinematics and publish."""
        cpu = self.cpu_ns
        for phase, ns in phases.items():
            cpu[phase] += ns

    def cpu_per_cycle(self) -> dict[str, float]:
        """Mean thread CPU time per cycle (s) of each phase since start."""
        cycles = max(self.cycles, 1)
        return {phase: total / 1e9 / cycles for phase, total in self.cpu_ns.items()}

    def rate_hz(self) -> float:
        """Mean cycle rate over the periods held."""
        periods = self.periods.recent()
        return 1e9 * periods.size / float(periods.sum()) if periods.size else 0.0
