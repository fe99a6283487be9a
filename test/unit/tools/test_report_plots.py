# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""report_plots: the report's figure, its envelopes and its loop period histogram."""
import math

from harness.session_bags import write_bag
from kraft_master_driver.tools import report_data, report_plots
import numpy as np
import pytest


def test_envelope_keeps_the_extremes_of_each_bucket():
    t = np.arange(100_000) / 1000.0
    values = np.sin(t)[:, None] * [1.0, 2.0]
    values[12345] = [50.0, -50.0]
    values[777] = math.nan
    times, reduced = report_plots.envelope(t, values, buckets=1000)
    assert len(times) == len(reduced) == 2000
    assert reduced.max(axis=0)[0] == 50.0 and reduced.min(axis=0)[1] == -50.0
    assert not np.isnan(reduced).any()


def test_period_histogram_keeps_every_outlier_in_a_labelled_last_bin():
    periods = np.concatenate([np.full(9998, 1.0), [69.9, 12.0]])
    counts, edges = report_plots.period_histogram(periods)
    assert counts.sum() == len(periods)
    assert counts[-1] == 2 and edges[-2] == pytest.approx(3.0)
    arm = report_data.ArmData(
        '', 'right', np.cumsum(np.r_[0, periods * 1e6]).astype(np.int64),
        *(np.full((len(periods) + 1, n), np.nan) for n in (6, 6, 6, 6, 3, 4)),
        np.empty(0, np.int64), np.empty((0, 6)), '', [], [], [])
    (histogram,) = [ax for ax in report_plots.draw(arm).axes
                    if ax.get_title().startswith('loop period')]
    assert [t.get_text() for t in histogram.texts] == ['2 over 3.00 ms\nmax 69.9 ms']
    assert 'max 69.900 ms' in histogram.get_title()


def test_a_wrist_that_did_not_move_is_drawn_as_a_point_said_no_motion(tmp_path):
    bag = tmp_path / 'session'
    write_bag(bag, 'mcap', {'/right': ('right', 4)})
    (moving,) = report_data.read_arms(bag)
    still = moving._replace(wrist=np.repeat(moving.wrist[:1], len(moving.wrist), axis=0))
    for arm_data, said in ((moving, []), (still, ['no motion (within 0.1 mm)'])):
        figure = report_plots.draw(arm_data)
        planes = [ax for ax in figure.axes if ax.get_title().startswith('wrist path, ')]
        assert len(planes) == 3
        for ax in planes:
            assert [t.get_text() for t in ax.texts] == said
            assert ax.lines and ax.lines[0].get_marker() == ('o' if said else 'None')
