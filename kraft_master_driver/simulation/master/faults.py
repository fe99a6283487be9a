# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Fault switches of the simulated device, for tests: dropped replies, corrupted bytes, stalls.

Random faults draw from one stream of their own, so that a seed repeats them. Unplugging the
port is the transports' part (transport.py); garbage bytes come from here.
"""
import time


def _rate(value, name):
    """Return `value` as a probability, or raise ValueError naming `name`."""
    rate = float(value)
    if not 0.0 <= rate <= 1.0:
        raise ValueError(f'{name} must be within 0..1, got {value!r}')
    return rate


class FaultInjector:
    """Decides which replies are lost or corrupted, and when the device stalls."""

    def __init__(self, fault_random, drop_reply_rate=0.0, corrupt_byte_rate=0.0):
        """Draw every random fault from `fault_random` (a random.Random)."""
        self._random = fault_random
        self.drop_reply_rate = drop_reply_rate
        self.corrupt_byte_rate = corrupt_byte_rate
        self._stall_until = 0.0

    @property
    def drop_reply_rate(self):
        """Probability (0..1) that a reply is lost after the command was applied."""
        return self._drop_rate

    @drop_reply_rate.setter
    def drop_reply_rate(self, rate):
        self._drop_rate = _rate(rate, 'drop_reply_rate')

    @property
    def corrupt_byte_rate(self):
        """Probability (0..1) per outgoing byte that random bits of it are flipped."""
        return self._corrupt_rate

    @corrupt_byte_rate.setter
    def corrupt_byte_rate(self, rate):
        self._corrupt_rate = _rate(rate, 'corrupt_byte_rate')

    def stall(self, ms):
        """Stall the device for `ms` milliseconds from now."""
        if not ms >= 0:
            raise ValueError(f'stall needs a duration >= 0 ms, got {ms!r}')
        self._stall_until = time.monotonic() + ms / 1000.0

    def stalled(self, now):
        """Return True while a stall lasts at `now` (monotonic seconds)."""
        return now < self._stall_until

    def drops_reply(self):
        """Return True if the next reply is to be lost."""
        return bool(self._drop_rate) and self._random.random() < self._drop_rate

    def corrupt(self, reply):
        """
        Return `reply` with random bits flipped in some bytes, and how many bytes were hit.

        Each byte is hit with probability corrupt_byte_rate.
        """
        if not self._corrupt_rate:
            return reply, 0
        data = bytearray(reply)
        chance = self._random.random
        hit = 0
        for index in range(len(data)):
            if chance() < self._corrupt_rate:
                data[index] ^= self._random.randrange(1, 256)
                hit += 1
        return bytes(data), hit

    def garbage(self, n_bytes):
        """Return `n_bytes` random bytes."""
        return self._random.randbytes(n_bytes)
