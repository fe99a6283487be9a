# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The link emulator's delay line (core/delay_line.py): delays, jitter, bursty loss, order."""
from kraft_master_driver.core.delay_line import DelayLine, LinkModel
import numpy as np
import pytest

PERIOD = 0.001  # s between admitted messages in the delay line's tests (1 kHz)


def admit_stream(line, count, period=PERIOD):
    """Admit `count` messages `period` apart; return their release times (None when lost)."""
    return [line.admit(i * period) for i in range(count)]


def burst_lengths(lost_flags):
    """Return the lengths of the runs of consecutive True in `lost_flags`."""
    runs, length = [], 0
    for lost in list(lost_flags) + [False]:
        if lost:
            length += 1
        elif length:
            runs.append(length)
            length = 0
    return runs


def test_fixed_delay_releases_each_message_exactly_that_much_later():
    dues = admit_stream(DelayLine(LinkModel(delay=0.05)), 1000)
    assert dues == pytest.approx([i * PERIOD + 0.05 for i in range(1000)], abs=1e-12)


def test_jitter_stays_within_its_range_never_below_the_delay_and_keeps_order():
    line = DelayLine(LinkModel(delay=0.02, jitter=0.01), seed=3)
    dues = np.array(admit_stream(line, 20000))
    delays = dues - np.arange(20000) * PERIOD
    assert delays.min() >= 0.02
    # Order kept: a message never overtakes the one before; a late one holds the next back.
    assert np.all(np.diff(dues) >= 0.0)
    assert delays.max() <= 0.03 + 1e-12
    # The jitter is really there: the delays spread over most of the range.
    assert np.percentile(delays, 99) - delays.min() > 0.008


@pytest.mark.parametrize('loss, burst', [(0.01, 0.0), (0.1, 0.0), (0.1, 5.0), (0.3, 2.0)])
def test_loss_rate_and_mean_burst_length_match_the_model(loss, burst):
    count = 200000
    line = DelayLine(LinkModel(loss=loss, loss_burst=burst), seed=11)
    lost = [due is None for due in admit_stream(line, count)]
    runs = burst_lengths(lost)
    assert sum(lost) / count == pytest.approx(loss, rel=0.1)
    expected_burst = burst or 1.0 / (1.0 - loss)
    assert np.mean(runs) == pytest.approx(expected_burst, rel=0.1)
    assert line.stats.dropped == sum(lost) and line.stats.received == count


def test_bursty_loss_comes_in_long_runs_independent_loss_does_not():
    independent = burst_lengths(
        d is None for d in admit_stream(DelayLine(LinkModel(loss=0.05), seed=5), 100000))
    bursty = burst_lengths(
        d is None for d in admit_stream(
            DelayLine(LinkModel(loss=0.05, loss_burst=10.0), seed=5), 100000))
    assert max(independent) < 8 < max(bursty)


def test_the_same_seed_gives_the_same_fates():
    model = LinkModel(delay=0.01, jitter=0.005, loss=0.1, loss_burst=3.0)
    assert (admit_stream(DelayLine(model, seed=7), 5000)
            == admit_stream(DelayLine(model, seed=7), 5000))


def test_statistics_count_and_summarise_the_released_delays():
    line = DelayLine(LinkModel(delay=0.01))
    for i in range(100):
        due = line.admit(float(i))
        line.record(due + i * 1e-5, float(i))
    summary = line.stats.summary()
    assert (summary['received'], summary['relayed'], summary['dropped']) == (100, 100, 0)
    assert float(summary['delay min ms']) == pytest.approx(10.0)
    assert float(summary['delay max ms']) == pytest.approx(10.99)
    assert float(summary['delay p50 ms']) == pytest.approx(10.5, abs=0.01)


@pytest.mark.parametrize('model, fragment', [
    (LinkModel(delay=-0.1), 'delay must be a finite number >= 0'),
    (LinkModel(jitter=float('nan')), 'jitter must be a finite number >= 0'),
    (LinkModel(delay='1'), 'delay must be a finite number >= 0'),
    (LinkModel(loss=1.0), 'loss must be in [0, 1)'),
    (LinkModel(loss=0.1, loss_burst=0.5), 'loss_burst must be 0 (independent) or >= 1'),
    (LinkModel(loss=0.9, loss_burst=2.0), 'loss 0.9 needs loss_burst >= 9'),
])
def test_bad_models_raise_naming_the_field(model, fragment):
    with pytest.raises(ValueError, match=None) as raised:
        DelayLine(model)
    assert fragment in str(raised.value)


def test_a_delay_step_applies_to_later_messages_and_keeps_order():
    line = DelayLine(LinkModel(delay=0.5))
    assert line.admit(0.0) == 0.5
    line.change(LinkModel(delay=0.0))
    # Admitted after the step, it may not overtake the one still in the line.
    assert line.admit(0.1) == 0.5
    assert line.admit(1.0) == 1.0
    line.change(LinkModel(delay=0.2))
    assert line.admit(2.0) == 2.2


def test_a_bad_change_raises_and_leaves_the_model():
    line = DelayLine(LinkModel(delay=0.1))
    with pytest.raises(ValueError, match='loss must be in'):
        line.change(LinkModel(loss=1.0))
    assert line.model == LinkModel(delay=0.1)


def test_a_blackout_loses_every_message_until_it_is_lifted():
    line = DelayLine(LinkModel(delay=0.01))
    line.blackout = True
    assert [line.admit(float(i)) for i in range(5)] == [None] * 5
    line.blackout = False
    assert line.admit(10.0) == pytest.approx(10.01)
    assert (line.stats.received, line.stats.dropped) == (6, 5)
