# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The figure of kraft_master_report: one arm's session drawn with matplotlib.

Time series are drawn as min/max envelopes, so a million samples draw as fast as a thousand;
panels with nothing to show say why.
"""
import math

from kraft_master_driver.core import kinematics
from kraft_master_driver.tools.report_data import (
    ArmData, diagnostics_series, last_values, link_errors, LOOP_COUNTERS, loop_periods,
    Recalibration, ROUND_TRIP_KEYS)
from matplotlib.figure import Figure
import numpy as np

PLOT_BUCKETS = 1500  # time series are drawn as min/max envelopes of this many buckets
PATH_POINTS = 5000  # wrist paths are drawn with at most this many points
STILL_MM = 0.1  # a wrist path that spans less (every axis) is drawn as a point: "no motion"
PERIOD_BINS = 100  # histogram bins up to the clip, and one more for everything above it
PLANES = (('x', 'y'), ('x', 'z'), ('y', 'z'))
AXES = {'x': 0, 'y': 1, 'z': 2}


def envelope(t: np.ndarray, values: np.ndarray, buckets: int = PLOT_BUCKETS
             ) -> tuple[np.ndarray, np.ndarray]:
    """Return (t, values) reduced to the min and max of each of `buckets` runs of samples."""
    if len(t) <= 2 * buckets:
        return t, values
    starts = np.linspace(0, len(t), buckets, endpoint=False).astype(np.int64)
    low = np.fmin.reduceat(values, starts, axis=0)
    high = np.fmax.reduceat(values, starts, axis=0)
    return np.repeat(t[starts], 2), np.stack([low, high], axis=1).reshape(
        2 * buckets, *values.shape[1:])


def _thin(values, points=PATH_POINTS):
    return values[::max(1, len(values) // points)]


def _no_data(ax, text):
    ax.text(0.5, 0.5, text, ha='center', va='center', transform=ax.transAxes, color='0.4')


def _draw_joints(axes, t, arm_data, recalibration):
    lower, upper = kinematics.joint_limits()
    th2 = arm_data.position[:, 1]
    for joint, ax in enumerate(axes):
        ax.set_title(kinematics.JOINT_NAMES[joint])
        ax.set_ylabel('deg')
        if joint == 2 and np.isfinite(th2).any():
            # The elbow's upper stop falls as th2 grows (four-bar coupling).
            th2_range = (0.0, upper[1])
            elbow_upper = np.interp(th2, th2_range,
                                    [kinematics.joint_limits(x)[1][2] for x in th2_range])
            ax.plot(*envelope(t, np.degrees(elbow_upper)), color='darkorange', lw=0.8, ls='--',
                    label='upper stop, moves with th2')
            ax.axhline(math.degrees(lower[2]), color='red', lw=0.8, ls='--', label='stop')
        else:
            for limit in (lower[joint], upper[joint]):
                ax.axhline(math.degrees(limit), color='red', lw=0.8, ls='--')
        if not np.isfinite(arm_data.position[:, joint]).any():
            _no_data(ax, 'no joint_states')
        else:
            ax.plot(*envelope(t, np.degrees(arm_data.position[:, joint])), lw=0.8,
                    label='recorded')
        if recalibration is not None:
            ax.plot(*envelope(t, np.degrees(recalibration.position[:, joint])), lw=0.8,
                    ls='--', label='recalibrated')
        if (recalibration is not None or joint == 2) and ax.get_legend_handles_labels()[0]:
            ax.legend(loc='upper right', fontsize='small')


def _draw_paths(ax3d, planes, arm_data, recalibration):
    paths = [('recorded', arm_data.wrist)]
    if recalibration is not None:
        paths.append(('recalibrated', recalibration.wrist))
    paths = [(label, _thin(wrist[np.all(np.isfinite(wrist), axis=1)]) * 1e3)
             for label, wrist in paths]
    # A path of one point (the wrist did not move) is no line: it is marked, and said.
    still = all(np.ptp(wrist, axis=0).max() < STILL_MM for _, wrist in paths if len(wrist))
    ax3d.set_title('wrist path (mm)')
    for label, wrist in paths:
        if len(wrist):
            ax3d.plot(wrist[:, 0], wrist[:, 1], wrist[:, 2], lw=0.6, label=label,
                      marker='o' if still else None)
    ax3d.set_xlabel('x')
    ax3d.set_ylabel('y')
    ax3d.set_zlabel('z')
    for ax, (a, b) in zip(planes, PLANES):
        ax.set_title(f'wrist path, {a}-{b} plane (mm)')
        ax.set_xlabel(f'{a} (mm)')
        ax.set_ylabel(f'{b} (mm)')
        ax.set_aspect('equal', adjustable='datalim')
        for label, wrist in paths:
            if len(wrist):
                ax.plot(wrist[:, AXES[a]], wrist[:, AXES[b]], lw=0.6, label=label,
                        marker='o' if still else None)
        if not any(len(wrist) for _, wrist in paths):
            _no_data(ax, 'no pose')
        elif still:
            ax.text(0.5, 0.9, f'no motion (within {STILL_MM:g} mm)', ha='center',
                    transform=ax.transAxes, color='0.4')
    if recalibration is not None and any(len(wrist) for _, wrist in paths):
        planes[0].legend(fontsize='small')


def _draw_wrench(force_ax, moment_ax, t0, arm_data):
    force_ax.set_title(f'task force ({arm_data.wrench_frame or "frame unknown"})')
    moment_ax.set_title(f'task moment ({arm_data.wrench_frame or "frame unknown"})')
    force_ax.set_ylabel('N')
    moment_ax.set_ylabel('N*m')
    if not len(arm_data.wrench):
        _no_data(force_ax, 'no wrench')
        _no_data(moment_ax, 'no wrench')
        return
    t = (arm_data.wrench_time - t0) / 1e9
    for ax, columns in ((force_ax, slice(0, 3)), (moment_ax, slice(3, 6))):
        times, values = envelope(t, arm_data.wrench[:, columns])
        for axis, name in enumerate('xyz'):
            ax.plot(times, values[:, axis], lw=0.8, label=name)
        ax.legend(loc='upper right', fontsize='small')
        ax.set_xlabel('time (s)')


def _draw_torques(ax, t, arm_data):
    ax.set_title('commanded joint torques')
    ax.set_ylabel('N*m')
    ax.set_xlabel('time (s)')
    if not np.isfinite(arm_data.effort).any():
        _no_data(ax, 'no joint_states effort')
        return
    times, values = envelope(t, arm_data.effort)
    for joint, name in enumerate(kinematics.JOINT_NAMES):
        ax.plot(times, values[:, joint], lw=0.8, label=name)
    ax.legend(loc='upper right', fontsize='small', ncol=2)


def _draw_periods(ax, periods):
    ax.set_title('loop period')
    ax.set_xlabel('period between samples (ms)')
    ax.set_ylabel('samples')
    periods = periods[np.isfinite(periods) & (periods > 0)] * 1e3
    if not len(periods):
        _no_data(ax, 'fewer than two samples')
        return
    median, p99 = np.percentile(periods, (50, 99))
    counts, edges = period_histogram(periods)
    clip, width = edges[-2], edges[1] - edges[0]
    colours = ['C0'] * PERIOD_BINS + ['red']
    ax.bar(edges[:-1], counts, width=width, align='edge', color=colours, log=True)
    over = int(counts[-1])
    if over:
        ax.annotate(f'{over} over {clip:.2f} ms\nmax {periods.max():.1f} ms',
                    (edges[-2] + width / 2, over), xytext=(-8, 12),
                    textcoords='offset points', ha='right', color='red', fontsize='small',
                    arrowprops={'arrowstyle': '->', 'color': 'red'})
    ax.set_title(f'loop period: median {median:.3f} ms, p99 {p99:.3f} ms, '
                 f'max {periods.max():.3f} ms')


def period_histogram(periods_ms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """
    Return (counts, edges) of periods (ms): PERIOD_BINS bins up to a clip, then one more.

    The clip is three medians or 1.1 times the 99th percentile, whichever is larger; the
    last bin counts every period above it, so no outlier is left out.
    """
    median, p99 = np.percentile(periods_ms, (50, 99))
    clip = max(3.0 * median, p99 * 1.1)
    width = clip / PERIOD_BINS
    edges = np.linspace(0.0, clip + width, PERIOD_BINS + 2)
    counts, _ = np.histogram(np.minimum(periods_ms, clip + width / 2), bins=edges)
    return counts, edges


def _draw_link_errors(ax, t0, arm_data):
    ax.set_title('link errors (diagnostics)')
    ax.set_xlabel('time (s)')
    ax.set_ylabel('count since the driver started')
    times, counters = link_errors(arm_data.diagnostics)
    if not arm_data.diagnostics:
        _no_data(ax, 'no diagnostics')
    elif not counters:
        _no_data(ax, f'no link errors in {len(arm_data.diagnostics)} diagnostics messages')
    for name, values in counters.items():
        ax.step((times - t0) / 1e9, values, where='post', label=f'{name} ({values[-1]:.0f})')
    if counters:
        ax.yaxis.get_major_locator().set_params(integer=True)
        ax.legend(loc='upper left', fontsize='small')


def _draw_loop_counters(ax, t0, arm_data):
    ax.set_title('late and missed loop cycles (diagnostics)')
    ax.set_xlabel('time (s)')
    ax.set_ylabel('count since the driver started')
    times, series = diagnostics_series(arm_data.diagnostics, LOOP_COUNTERS)
    if not arm_data.diagnostics:
        _no_data(ax, 'no diagnostics')
        return
    if not any(np.isfinite(values).any() for values in series.values()):
        _no_data(ax, 'the diagnostics do not count late and missed cycles')
        return
    last = last_values(series)
    for name, values in series.items():
        ax.step((times - t0) / 1e9, values, where='post',
                label=f'{name} ({last.get(name, math.nan):.0f})')
    if not any(last.values()):
        _no_data(ax, f'no late or missed cycles in {len(arm_data.diagnostics)} diagnostics '
                     'messages')
    ax.yaxis.get_major_locator().set_params(integer=True)
    ax.legend(loc='upper left', fontsize='small')


def _draw_round_trip(ax, t0, arm_data):
    ax.set_title('link round trip per diagnostics period (ms)')
    ax.set_xlabel('time (s)')
    ax.set_ylabel('ms')
    times, series = diagnostics_series(arm_data.diagnostics, ROUND_TRIP_KEYS)
    if not any(np.isfinite(values).any() for values in series.values()):
        _no_data(ax, 'no round trip in the diagnostics')
        return
    for key, values in series.items():
        ax.plot((times - t0) / 1e9, values, marker='.', lw=0.8,
                label=key.removeprefix('link round trip ').removesuffix(' (ms)'))
    ax.legend(loc='upper left', fontsize='small')


def draw(arm_data: ArmData, recalibration: Recalibration | None = None,
         title: str = '') -> Figure:
    """Return the report Figure of one arm."""
    figure = Figure(figsize=(22, 28))
    grid = figure.add_gridspec(6, 4, left=0.04, right=0.98, bottom=0.03, top=0.955,
                               hspace=0.32, wspace=0.22)
    t0 = arm_data.stamp[0] if len(arm_data.stamp) else (
        arm_data.wrench_time[0] if len(arm_data.wrench_time) else 0)
    t = (arm_data.stamp - t0) / 1e9
    joints = [figure.add_subplot(grid[row, column]) for row in (0, 1) for column in (0, 1, 2)]
    for ax in joints[3:]:
        ax.set_xlabel('time (s)')
    _draw_joints(joints, t, arm_data, recalibration)
    _draw_paths(figure.add_subplot(grid[0:2, 3], projection='3d'),
                [figure.add_subplot(grid[2, column]) for column in (0, 1, 2)],
                arm_data, recalibration)
    _draw_periods(figure.add_subplot(grid[2, 3]), loop_periods(arm_data.stamp))
    _draw_wrench(figure.add_subplot(grid[3, 0:2]), figure.add_subplot(grid[3, 2:4]), t0,
                 arm_data)
    _draw_torques(figure.add_subplot(grid[4, 0:2]), t, arm_data)
    _draw_link_errors(figure.add_subplot(grid[4, 2:4]), t0, arm_data)
    _draw_loop_counters(figure.add_subplot(grid[5, 0:2]), t0, arm_data)
    _draw_round_trip(figure.add_subplot(grid[5, 2:4]), t0, arm_data)
    figure.suptitle(title, fontsize='x-large')
    return figure
