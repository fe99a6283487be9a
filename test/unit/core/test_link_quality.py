# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Tests of the link-quality monitor (core.link_quality)."""
import random

from kraft_master_driver.core.link_quality import LinkMonitor
import pytest

MS = 1_000_000


def test_link_monitor_delay_and_loss():
    monitor = LinkMonitor()
    assert monitor.summary() is None
    for k in range(1000):
        if k % 10 != 3:  # 10 % lost
            monitor.add(k * 2 * MS, k * 2 * MS + (5 + k % 3) * MS)
    median, p99, largest, lost = monitor.summary()
    assert median == pytest.approx(0.006)
    assert p99 == pytest.approx(0.007) and largest == pytest.approx(0.007)
    assert lost == pytest.approx(0.1, abs=0.002)
    assert monitor.summary() is None, 'each summary starts a new window'


def test_link_monitor_counts_ticks_a_stalled_sender_skipped_as_lost():
    jittery, stalled = LinkMonitor(), LinkMonitor()
    rng = random.Random(7)
    for k in range(500):  # 2 ms ticks, each late by up to 1.5 ms: none missing
        stamp = k * 2 * MS + rng.randrange(0, 3 * MS // 2)
        jittery.add(stamp, stamp + MS)
    for k in range(500):  # every 50th tick starts a 20 ms stall: 9 ticks skipped, not sent
        if k % 50 not in range(1, 10):
            stalled.add(k * 2 * MS, k * 2 * MS + MS)
    assert jittery.summary()[3] < 0.01
    assert stalled.summary()[3] == pytest.approx(0.18, abs=0.01)
