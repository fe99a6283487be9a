# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The session soak's figure: one fault of each kind, as the recorder kept it (teleop_soak.py).

A panel per kind, its first fault, from 1 s before it to 3 s after it cleared: the master's
wrist height (from joint_states' angles, by the package's kinematics) and the arm's commanded
height (servo_cp), each from where it was when the fault came (mm), and the master's torques
(the norm of joint_states' effort, N*m, right axis); the fault's span shaded. Receive times of
the bag, as the checker reads them.
"""
import math

from kraft_master_driver.bag.reader import read_topics
from kraft_master_driver.core import kinematics
import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)
import numpy as np  # noqa: E402

BEFORE_S, AFTER_S = 1.0, 3.0
COLUMNS = 4
EVERY = 5  # of the master's 1 kHz angles, one in this many through the kinematics


def _window(data, field, start, end):
    """Return (times, values) of `field` in [start, end] (s), None if the topic is empty."""
    if data is None or not len(data):
        return None
    times = data.log_time / 1e9
    inside = (times >= start) & (times <= end)
    return times[inside], data.fields[field][inside]


def draw(bag, faults, output):
    """Draw the first fault of each kind in `faults` (dicts) from `bag` into `output` (PNG)."""
    data = read_topics(bag, ['/servo_cp', '/joint_states'])
    first = {}
    for fault in faults:
        first.setdefault(fault['kind'], fault)
    rows = math.ceil(len(first) / COLUMNS)
    figure, axes = plt.subplots(rows, COLUMNS, figsize=(4.2 * COLUMNS, 2.6 * rows),
                                squeeze=False)
    for ax, (kind, fault) in zip(axes.flat, sorted(first.items())):
        start, end = fault['start'], fault['end']
        span = (start - BEFORE_S, end + AFTER_S)
        window = _window(data.get('/joint_states'), 'position', *span)
        if window is not None and len(window[0]):
            times, angles = window[0][::EVERY], window[1][::EVERY]
            height = np.array([kinematics.forward(theta)[2, 3] for theta in angles])
            ax.plot(times - start, 1e3 * (height - height[0]), color='#1f4e79', linewidth=0.9,
                    label='master z')
        window = _window(data.get('/servo_cp'), 'position', *span)
        if window is not None and len(window[0]):
            times, position = window
            ax.plot(times - start, 1e3 * (position[:, 2] - position[0, 2]), color='#c0392b',
                    linewidth=0.9, label='arm command z')
        torque_axis = ax.twinx()
        window = _window(data.get('/joint_states'), 'effort', *span)
        if window is not None and len(window[0]):
            times, effort = window
            torque_axis.plot(times - start, np.linalg.norm(effort, axis=1), color='#7f8c8d',
                             linewidth=0.7, label='|torque|')
        torque_axis.set_ylabel('N*m', fontsize=7)
        torque_axis.tick_params(labelsize=7)
        ax.axvspan(0.0, end - start, color='#f5b041', alpha=0.3, linewidth=0)
        ax.set_title(kind, fontsize=8)
        ax.set_ylabel('mm', fontsize=7)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(first):]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=6, loc='upper left')
    figure.supxlabel('s from the fault (shaded: while it lasted)', fontsize=8)
    figure.tight_layout()
    figure.savefig(output, dpi=90)
    plt.close(figure)
