# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
A one-way network link in software: delay, order-keeping jitter, loss and loss bursts.

    line = DelayLine(LinkModel(delay=0.05, jitter=0.01, loss=0.01, loss_burst=3), seed=1)
    due = line.admit(now)        # None: lost; else the time the message must leave
    line.record(now_released, now_admitted)   # once it has left

Each message is delayed by `delay` plus a uniform draw in [0, jitter], never less than
`delay`, and never released before the message admitted before it (the link keeps order, as
one TCP-less path between two hosts does; jitter that would reorder is absorbed into a longer
wait). change() swaps the model mid-run (a delay step); `blackout` loses every message while
set. Loss follows a two-state Gilbert chain: in the bad state every message is lost, in the
good state none; its two transition probabilities come from the long-run loss rate and the mean
length of a run of lost messages (loss_burst). loss_burst 0 means independent losses.

Plain Python, no ROS: the link emulator node (link_emulator) moves the messages.
"""
import collections
import math
import random
from typing import NamedTuple


class LinkModel(NamedTuple):
    """What one direction of the link does to messages (seconds, fractions, messages)."""

    delay: float = 0.0
    jitter: float = 0.0
    loss: float = 0.0
    loss_burst: float = 0.0

    def checked(self) -> 'LinkModel':
        """Return the model in floats if every field is valid, else raise ValueError."""
        for name, value in self._asdict().items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                    math.isfinite(value) and value >= 0.0):
                raise ValueError(f'{name} must be a finite number >= 0, got {value!r}')
        if self.loss >= 1.0:
            raise ValueError(f'loss must be in [0, 1), got {self.loss}')
        if 0.0 < self.loss_burst < 1.0:
            raise ValueError(f'loss_burst must be 0 (independent) or >= 1, got {self.loss_burst}')
        if self.loss_burst and self.loss / (1.0 - self.loss) > self.loss_burst:
            raise ValueError(f'loss {self.loss} needs loss_burst >= '
                             f'{self.loss / (1.0 - self.loss):.3g} messages')
        return LinkModel(*map(float, self))

    def transitions(self) -> tuple[float, float]:
        """Return (p_good_to_bad, p_bad_to_good) of the Gilbert chain, per message."""
        if self.loss == 0.0:
            return 0.0, 1.0
        burst = self.loss_burst or 1.0 / (1.0 - self.loss)
        leave_bad = 1.0 / burst
        return self.loss * leave_bad / (1.0 - self.loss), leave_bad


class DelayStatistics:
    """Counts and the delays of the last `window` released messages (seconds)."""

    def __init__(self, window: int = 10000) -> None:
        """Start with nothing counted."""
        self.received = 0
        self.dropped = 0
        self.released = 0
        self.delays: collections.deque[float] = collections.deque(maxlen=window)

    def percentiles(self, *quantiles: float) -> tuple[float, ...] | None:
        """Return the given quantiles (0..1) of the recent delays, or None when there are none."""
        if not self.delays:
            return None
        ordered = sorted(self.delays)
        last = len(ordered) - 1
        return tuple(ordered[min(last, int(round(q * last)))] for q in quantiles)

    def summary(self) -> dict[str, int | str]:
        """Return a dict of the counts and recent delay percentiles (ms), for diagnostics."""
        values: dict[str, int | str] = {
            'received': self.received, 'relayed': self.released, 'dropped': self.dropped,
            'loss': f'{self.dropped / self.received:.4f}' if self.received else '0'}
        points = self.percentiles(0.0, 0.5, 0.99, 1.0)
        if points:
            for key, value in zip(('min', 'p50', 'p99', 'max'), points):
                values[f'delay {key} ms'] = f'{value * 1e3:.3f}'
        return values


class DelayLine:
    """Decides each message's fate (lost, or the time it leaves) and records what happened."""

    def __init__(self, model: LinkModel, seed: int | None = None) -> None:
        """Use `model` (a LinkModel) with a random generator seeded by `seed`."""
        self.model = model.checked()
        self.rng = random.Random(seed)
        self.to_bad, self.to_good = self.model.transitions()
        self.bad = False
        self.blackout = False  # every message lost while True
        self.last_due = -math.inf
        self.stats = DelayStatistics()

    def change(self, model: LinkModel) -> None:
        """
        Apply `model` to the messages admitted from now on; raise ValueError if it is invalid.

        Those already admitted keep their times, and order is still kept: after a shorter
        delay a message leaves no sooner than the one admitted before it.
        """
        model = model.checked()
        self.to_bad, self.to_good = model.transitions()
        self.model = model

    def admit(self, now: float) -> float | None:
        """Take a message arriving at `now` (s); return its release time, or None if lost."""
        self.stats.received += 1
        if self.blackout:
            self.stats.dropped += 1
            return None
        self.bad = (self.rng.random() >= self.to_good) if self.bad else (
            self.rng.random() < self.to_bad)
        if self.bad:
            self.stats.dropped += 1
            return None
        due = now + self.model.delay
        if self.model.jitter:
            due += self.rng.random() * self.model.jitter
        self.last_due = max(due, self.last_due)
        return self.last_due

    def record(self, released: float, admitted: float) -> None:
        """Count one message that arrived at `admitted` and left at `released` (s)."""
        self.stats.released += 1
        self.stats.delays.append(released - admitted)
