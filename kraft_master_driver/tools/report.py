# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_report: a PNG report and a CSV of a recorded driver session (rosbag2).

For each arm in the bag (topics joint_states, pose, pots, wrench, diagnostics under a
namespace such as /left, or at the root) it draws the joint angles over time against the
Table II limits, the wrist path in 3-D and in the three planes, the task wrench and the
commanded joint torques, the loop period histogram (from the joint_states stamps) and
the driver's diagnostics (link error counts, late and missed cycles, link round trip; read
from <namespace>/diagnostics or /diagnostics by the node's name), and writes one CSV row per
sample: stamp_ns, six positions (rad), six velocities (rad/s), six efforts (N*m), six pots
(counts), wrist x y z (m) and quaternion qx qy qz qw. Missing values are empty fields.

With --calibration the joint angles and wrist poses are recomputed from the recorded raw
pots with that calibration and drawn against the recorded ones; the CSV then has recal_
columns as well. Decoding (bag/reader.py) and everything after it work on whole
arrays: a bag of a million samples takes some 15 s (benchmarks/report.py).
"""
import argparse
import math
from pathlib import Path
import sys
import time
from typing import NamedTuple

from kraft_master_driver.bag.common import DRIVER_TOPICS, SessionError
from kraft_master_driver.bag.reader import bag_topics, read_topics
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration, CalibrationError
from matplotlib.figure import Figure
import numpy as np

ARM_TOPICS = ('joint_states', 'pose', 'pots', 'wrench', 'diagnostics')
STATE_TOPICS = ('joint_states', 'pots', 'pose')  # one of them makes a namespace an arm
PLOT_BUCKETS = 1500  # time series are drawn as min/max envelopes of this many buckets
PATH_POINTS = 5000  # wrist paths are drawn with at most this many points
STILL_MM = 0.1  # a wrist path that spans less (every axis) is drawn as a point: "no motion"
CSV_CHUNK = 65536  # rows formatted at once
# Link counters that are not errors: progress, and what the driver did to commands.
LINK_NOT_ERRORS = ('cycles', 'replies', 'clamped_commands', 'nonfinite_commands',
                   'zero_commands', 'low_latency_failures')
LOOP_COUNTERS = ('late cycles', 'missed cycles')
ROUND_TRIP_KEYS = tuple(f'link round trip {label} (ms)' for label in ('median', 'p99', 'max'))
PERIOD_BINS = 100  # histogram bins up to the clip, and one more for everything above it
PLANES = (('x', 'y'), ('x', 'z'), ('y', 'z'))
AXES = {'x': 0, 'y': 1, 'z': 2}


class ArmData(NamedTuple):
    """One arm's samples, joined on the header stamp shared by joint_states, pose and pots."""

    namespace: str
    arm: str
    stamp: np.ndarray  # (N,) int64 ns
    position: np.ndarray  # (N, 6) rad; NaN where missing
    velocity: np.ndarray  # (N, 6) rad/s
    effort: np.ndarray  # (N, 6) N*m
    pots: np.ndarray  # (N, 6) counts
    wrist: np.ndarray  # (N, 3) m
    orientation: np.ndarray  # (N, 4) qx qy qz qw
    wrench_time: np.ndarray  # (W,) int64 ns, when the recorder received each wrench
    wrench: np.ndarray  # (W, 6) N, N*m
    wrench_frame: str
    diagnostics: list  # (receive time ns, {key: value}) of this driver's status
    missing: list  # topics absent from the bag
    notes: list  # other faults found: malformed messages, wrong types


class Recalibration(NamedTuple):
    """Joint angles and wrist poses recomputed from the raw pots with another calibration."""

    source: str
    position: np.ndarray  # (N, 6) rad
    wrist: np.ndarray  # (N, 3) m
    orientation: np.ndarray  # (N, 4)


# -- reading ---------------------------------------------------------------------------------


def find_namespaces(topics):
    """Return the namespaces ('' for the root) that hold a state topic of the driver."""
    namespaces = set()
    for topic in topics:
        namespace, _, name = topic.rpartition('/')
        if name in STATE_TOPICS:
            namespaces.add(namespace)
    return sorted(namespaces)


def _matcher(stamps, other_stamps):
    """Return a function taking rows stamped `other_stamps` (not empty) to rows at `stamps`."""
    if np.array_equal(stamps, other_stamps):
        return lambda values: values
    order = np.argsort(other_stamps, kind='stable')
    sorted_stamps = other_stamps[order]
    index = np.minimum(np.searchsorted(sorted_stamps, stamps), len(order) - 1)
    found = np.flatnonzero(sorted_stamps[index] == stamps)
    rows = order[index[found]]

    def match(values):
        out = np.full((len(stamps), values.shape[1]), np.nan)
        out[found] = values[rows]
        return out
    return match


def _six(values):
    """Return an (N, 6) array: the first six columns of `values`, NaN-padded."""
    out = np.full((len(values), 6), np.nan)
    width = min(6, values.shape[1])
    out[:, :width] = values[:, :width]
    return out


def _status_namespace(name):
    """
    Return the namespace of the node that named a status '<node>: <what>', or None.

    A full node name (/right/kraft_master_node) gives its namespace ('/right', '' at the
    root); a bare node name (kraft_master_node, as published on a namespaced topic) gives None.
    """
    node = name.partition(':')[0].strip().strip('/')
    return '/' + node.rpartition('/')[0] if '/' in node else None


def _diagnostics(namespace, topics):
    """
    Return (receive time, {key: value}) of the driver's status in `namespace`, in time order.

    topics maps each diagnostics topic read ('<namespace>/diagnostics', '/diagnostics') to
    its TopicData. A status is the driver's when it has link counters and its name carries
    the node's namespace, or a bare node name on the namespace's own diagnostics topic.
    """
    entries = []
    for topic, data in topics.items():
        for log_time, message in zip(data.log_time.tolist(), data.messages):
            for status in message.status:
                values = {pair.key: pair.value for pair in status.values}
                owner = _status_namespace(status.name)
                if any(key.startswith('link ') for key in values) and (
                        (owner or '/') == (namespace or '/') or
                        (owner is None and topic == f'{namespace}/diagnostics')):
                    entries.append((log_time, values))
                    break
    return sorted(entries, key=lambda entry: entry[0])


def _arm_of(namespace, calibration, position, wrist):
    """Return the arm of a namespace: its name, the calibration's, or the FK that fits."""
    name = namespace.rpartition('/')[2]
    if name in kinematics.ARMS:
        return name
    if calibration is not None:
        return calibration.arm
    usable = np.flatnonzero(np.all(np.isfinite(position), axis=1) &
                            np.all(np.isfinite(wrist), axis=1))
    if usable.size:
        sample = usable[0]
        errors = {arm: np.linalg.norm(kinematics.forward(position[sample], arm)[:3, 3] -
                                      wrist[sample]) for arm in kinematics.ARMS}
        return min(errors, key=errors.get)
    return 'right'


def diagnostics_topics(namespace):
    """Return where the driver in `namespace` may publish diagnostics: its own, /diagnostics."""
    return list(dict.fromkeys([f'{namespace}/diagnostics', '/diagnostics']))


def arm_topics(namespace):
    """Return the topics read for the driver in `namespace`."""
    return [f'{namespace}/{name}' for name in ARM_TOPICS if name != 'diagnostics'] + (
        diagnostics_topics(namespace))


def assemble(namespace, data, topics, calibration=None):
    """Build the ArmData of `namespace` from decoded topics `data` and the bag's `topics`."""
    missing, notes, found, diagnostics = [], [], {}, {}
    for name in ARM_TOPICS:
        candidates = (diagnostics_topics(namespace) if name == 'diagnostics' else
                      [f'{namespace}/{name}'])
        if not any(topic in topics for topic in candidates):
            missing.append(' or '.join(candidates))
        for topic in (topic for topic in candidates if topic in topics):
            expected = DRIVER_TOPICS[name]
            if topics[topic][0] != expected:
                notes.append(f'{topic} has type {topics[topic][0]}, expected {expected}; '
                             'ignored')
                continue
            if topic not in data:
                continue
            if name == 'diagnostics':
                diagnostics[topic] = data[topic]
            else:
                found[name] = data[topic]
            if data[topic].malformed:
                notes.append(f'{topic}: {data[topic].malformed} malformed messages skipped')
    primary = next((found[name] for name in ('joint_states', 'pots', 'pose')
                    if name in found and len(found[name])), None)
    stamp = np.empty(0, np.int64) if primary is None else primary.fields['stamp']

    matchers = {name: _matcher(stamp, data.fields['stamp'])
                for name, data in found.items() if name in STATE_TOPICS and len(data)}

    def column(name, field, width):
        if name not in matchers:
            return np.full((len(stamp), width), np.nan)
        values = found[name].fields[field]
        return matchers[name](_six(values) if width == 6 else values)

    position = column('joint_states', 'position', 6)
    wrist = column('pose', 'position', 3)
    wrench = found.get('wrench')
    return ArmData(
        namespace=namespace, arm=_arm_of(namespace, calibration, position, wrist),
        stamp=stamp, position=position,
        velocity=column('joint_states', 'velocity', 6),
        effort=column('joint_states', 'effort', 6), pots=column('pots', 'position', 6),
        wrist=wrist, orientation=column('pose', 'orientation', 4),
        wrench_time=np.empty(0, np.int64) if wrench is None else wrench.log_time,
        wrench=(np.empty((0, 6)) if wrench is None or not len(wrench) else
                np.hstack([wrench.fields['force'], wrench.fields['torque']])),
        wrench_frame='' if wrench is None else wrench.strings.get('frame_id', ''),
        diagnostics=_diagnostics(namespace, diagnostics),
        missing=missing, notes=notes)


def read_arms(bag, namespaces=None, calibration=None):
    """Read every arm of the bag (or those in `namespaces`); return a list of ArmData."""
    topics = bag_topics(bag)
    found = find_namespaces(topics)
    if namespaces:
        unknown = [ns for ns in namespaces if ns not in found]
        if unknown:
            raise SessionError(
                f'{bag}: no driver topics under {", ".join(ns or "/" for ns in unknown)}; '
                f'the bag has {", ".join(ns or "/" for ns in found) or "none"}')
        found = list(namespaces)
    if not found:
        raise SessionError(
            f'{bag}: no driver topics ({", ".join(STATE_TOPICS)}) in the bag')
    data = read_topics(bag, sorted({topic for ns in found for topic in arm_topics(ns)}))
    return [assemble(ns, data, topics, calibration) for ns in found]


# -- computing -------------------------------------------------------------------------------


def quaternions(rotations):
    """Return one unit quaternion row (x, y, z, w; w >= 0) per rotation matrix of (N, 3, 3)."""
    r = rotations
    r00, r11, r22 = r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]
    trace = r00 + r11 + r22
    # The same four cases as core.rotations.rotation_to_quaternion, ties broken alike, per row.
    case = np.where(trace > 0.0, 3, np.where((r00 > r11) & (r00 > r22), 0,
                                             np.where(r11 > r22, 1, 2)))
    q = np.empty((len(r), 4))
    with np.errstate(invalid='ignore', divide='ignore'):
        for index, rows in enumerate(case == k for k in range(4)):
            m = r[rows]
            if index == 3:
                s = 2.0 * np.sqrt(trace[rows] + 1.0)
                q[rows] = np.stack([(m[:, 2, 1] - m[:, 1, 2]) / s, (m[:, 0, 2] - m[:, 2, 0]) / s,
                                    (m[:, 1, 0] - m[:, 0, 1]) / s, 0.25 * s], axis=1)
                continue
            i, j, k = index, (index + 1) % 3, (index + 2) % 3
            s = 2.0 * np.sqrt(1.0 + m[:, i, i] - m[:, j, j] - m[:, k, k])
            q[rows, i] = 0.25 * s
            q[rows, j] = (m[:, i, j] + m[:, j, i]) / s
            q[rows, k] = (m[:, i, k] + m[:, k, i]) / s
            q[rows, 3] = (m[:, k, j] - m[:, j, k]) / s
    q[q[:, 3] < 0.0] *= -1.0
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def recalibrate(arm_data, calibration, lengths=None):
    """Recompute joint angles and wrist poses from the recorded pots with `calibration`."""
    position = calibration.pots_to_joints(arm_data.pots)
    wrist = np.full((len(position), 3), np.nan)
    orientation = np.full((len(position), 4), np.nan)
    valid = np.flatnonzero(np.all(np.isfinite(position), axis=1))
    if valid.size:
        poses = kinematics.forward(position[valid], arm_data.arm, lengths)
        wrist[valid] = poses[:, :3, 3]
        orientation[valid] = quaternions(poses[:, :3, :3])
    return Recalibration(calibration.source, position, wrist, orientation)


def loop_periods(stamp):
    """Return the periods (s) between consecutive samples."""
    return np.diff(stamp) / 1e9


def diagnostics_series(diagnostics, keys):
    """Return (times ns, {key: float values, NaN where absent}) of `keys` in `diagnostics`."""
    series = {}
    for key in keys:
        values = []
        for _, status in diagnostics:
            try:
                values.append(float(status.get(key, 'nan')))
            except ValueError:
                values.append(math.nan)
        series[key] = np.array(values)
    return np.array([t for t, _ in diagnostics], dtype=np.int64), series


def link_errors(diagnostics):
    """Return (times ns, {counter: values}) of the link error counters that ever rose."""
    keys = sorted({key for _, values in diagnostics for key in values
                   if key.startswith('link ') and not key.endswith('(ms)') and
                   key.removeprefix('link ') not in LINK_NOT_ERRORS})
    times, series = diagnostics_series(diagnostics, keys)
    return times, {key.removeprefix('link '): values for key, values in series.items()
                   if np.nanmax(values, initial=0.0) > 0}


def last_values(series):
    """Return {key: the last finite value} of diagnostics series (absent if none)."""
    return {key: values[np.isfinite(values)][-1] for key, values in series.items()
            if np.isfinite(values).any()}


# -- CSV -------------------------------------------------------------------------------------


# Text is built one character position at a time: rows of N characters, which numpy fills
# fast, NUL where a character is left out. Digits come from uint32 chunks of nine digits
# (integer division by a constant is fast for 32-bit integers).
_CHUNK = 10 ** 9
_ZERO = ord('0')


def _decimal_text(scaled, decimals, negative, present):
    """
    Render non-negative int64 `scaled` (in units of 10**-decimals) as a (width, N) array.

    Leading zeros of the integer part and trailing zeros of the fraction are left out, and
    so is the whole field where `present` is False.
    """
    chunks = []  # [digits above this chunk are non-zero (N,) bool, the chunk's value (N,)]
    while len(chunks) * 9 <= decimals or chunks[-1][0].any():
        scaled, chunk = np.divmod(scaled, _CHUNK)
        chunks.append([scaled != 0, chunk.astype(np.uint32)])
    fraction_seen = np.zeros(len(present), bool)
    fraction_rows, integer_rows = [], []
    for place in range(9 * len(chunks)):
        higher, value = chunks[place // 9]
        remaining = value != 0  # before this digit is taken
        if place > decimals and not (remaining.any() or higher.any()):
            break
        quotient = value // 10
        digit = (value - quotient * 10).astype(np.uint8) + _ZERO
        chunks[place // 9][1] = quotient
        if place < decimals:
            fraction_seen |= digit != _ZERO
            fraction_rows.append(digit * fraction_seen)
        else:
            integer_rows.append(digit * (remaining | higher | (place == decimals)))
    rows = [np.where(negative, ord('-'), 0).astype(np.uint8)] + integer_rows[::-1]
    if decimals:
        rows += [(fraction_seen * ord('.')).astype(np.uint8)] + fraction_rows[::-1]
    return np.stack(rows) * present.astype(np.uint8)


def number_text(values, decimals):
    """
    Render float or integer values as decimal text with at most `decimals` decimals.

    Returns a (width, N) uint8 array, NUL for characters left out; NaN and infinite values
    give empty fields. Values too large for exact fixed point are written by repr.
    """
    values = np.asarray(values)
    if values.dtype.kind in 'iu':
        return _decimal_text(np.abs(values.astype(np.int64)), 0, values < 0,
                             np.ones(len(values), bool))
    present = np.isfinite(values)
    finite = np.where(present, values, 0.0)
    largest = float(np.abs(finite).max(initial=0.0))
    if largest * 10 ** decimals >= 2 ** 53:
        text = np.array([repr(v) if ok else '' for v, ok in zip(finite.tolist(), present)],
                        dtype=bytes)
        return text.view(np.uint8).reshape(len(values), -1).T
    scaled = np.rint(np.abs(finite) * 10 ** decimals).astype(np.int64)
    return _decimal_text(scaled, decimals, (finite < 0) & (scaled > 0), present)


def csv_lines(columns):
    """Return the CSV bytes of equal-length columns, each (values, decimals)."""
    pieces = []
    for values, decimals in columns:
        pieces += [number_text(values, decimals),
                   np.full((1, len(values)), ord(','), np.uint8)]
    pieces[-1] = np.full((1, len(values)), ord('\n'), np.uint8)
    width = sum(len(piece) for piece in pieces)
    characters = np.zeros((-(-width // 8), 8, len(values)), np.uint8)
    np.concatenate(pieces, out=characters.reshape(-1, len(values))[:width])
    # Into row order eight character positions at a time (faster than one transpose),
    # then drop the NULs in one pass.
    lines = np.empty((len(values), len(characters), 8), np.uint8)
    for position in range(8):
        lines[:, :, position] = characters[:, position, :].T
    return lines.tobytes().translate(None, b'\0')


def csv_columns(arm_data, recalibration=None):
    """Return (header names, [(values, decimals)]) of the per-sample CSV."""
    names = list(kinematics.JOINT_NAMES)
    header, columns = ['stamp_ns'], [(arm_data.stamp, 0)]
    blocks = [('position', arm_data.position, 9), ('velocity', arm_data.velocity, 6),
              ('effort', arm_data.effort, 6)]
    for quantity, values, decimals in blocks:
        header += [f'{name}_{quantity}' for name in names]
        columns += [(values[:, i], decimals) for i in range(6)]
    header += [f'pot{i}' for i in range(1, 7)] + ['x', 'y', 'z', 'qx', 'qy', 'qz', 'qw']
    columns += [(arm_data.pots[:, i], 3) for i in range(6)]
    columns += [(arm_data.wrist[:, i], 9) for i in range(3)]
    columns += [(arm_data.orientation[:, i], 9) for i in range(4)]
    if recalibration is not None:
        header += [f'recal_{name}_position' for name in names]
        header += ['recal_x', 'recal_y', 'recal_z', 'recal_qx', 'recal_qy', 'recal_qz',
                   'recal_qw']
        columns += [(recalibration.position[:, i], 9) for i in range(6)]
        columns += [(recalibration.wrist[:, i], 9) for i in range(3)]
        columns += [(recalibration.orientation[:, i], 9) for i in range(4)]
    return header, columns


def write_csv(path, arm_data, recalibration=None):
    """Write the per-sample CSV of one arm."""
    header, columns = csv_columns(arm_data, recalibration)
    with open(path, 'wb') as stream:
        stream.write((','.join(header) + '\n').encode())
        for start in range(0, len(arm_data.stamp), CSV_CHUNK):
            part = slice(start, start + CSV_CHUNK)
            stream.write(csv_lines([(values[part], decimals) for values, decimals in columns]))


# -- figure ----------------------------------------------------------------------------------


def envelope(t, values, buckets=PLOT_BUCKETS):
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


def period_histogram(periods_ms):
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


def draw(arm_data, recalibration=None, title=''):
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


# -- command line ----------------------------------------------------------------------------


def summary(arm_data, recalibration=None):
    """Return text lines describing one arm's session."""
    label = arm_data.namespace or '/'
    count = len(arm_data.stamp)
    span = (arm_data.stamp[-1] - arm_data.stamp[0]) / 1e9 if count > 1 else 0.0
    lines = [f'{label} ({arm_data.arm} arm): {count} samples over {span:.3f} s']
    periods = loop_periods(arm_data.stamp)
    if len(periods):
        median, p99 = np.percentile(periods, (50, 99)) * 1e3
        lines.append(f'  loop period median {median:.3f} ms, p99 {p99:.3f} ms, '
                     f'max {periods.max() * 1e3:.3f} ms')
    if arm_data.diagnostics:
        _, counters = link_errors(arm_data.diagnostics)
        loop = last_values(diagnostics_series(arm_data.diagnostics, LOOP_COUNTERS)[1])
        errors = ', '.join(f'{name} {values[-1]:.0f}' for name, values in counters.items())
        lines.append(f'  {len(arm_data.diagnostics)} diagnostics messages: '
                     + ''.join(f'{key} {value:.0f}, ' for key, value in loop.items())
                     + f'link errors: {errors or "none"}')
    if arm_data.missing:
        lines.append(f'  missing topics: {", ".join(arm_data.missing)}')
    lines += [f'  {note}' for note in arm_data.notes]
    if recalibration is not None:
        change = np.degrees(np.abs(recalibration.position - arm_data.position))
        worst = np.max(np.nan_to_num(change, nan=-np.inf), axis=0, initial=-np.inf)
        moved = np.max(np.nan_to_num(np.linalg.norm(recalibration.wrist - arm_data.wrist,
                                                    axis=1), nan=-np.inf), initial=-np.inf)
        joints = ', '.join(f'{name} {value:.3f}' for name, value
                           in zip(kinematics.JOINT_NAMES, worst) if np.isfinite(value))
        lines.append(f'  recalibrated with {recalibration.source}: largest joint angle change '
                     f'(deg) {joints or "none (no pots and joint_states)"}')
        if np.isfinite(moved):
            lines.append(f'  largest wrist position change {moved * 1e3:.3f} mm')
    return lines


def _parser():
    parser = argparse.ArgumentParser(
        prog='kraft_master_report',
        description='Report of a recorded Kraft Master session (rosbag2, mcap or sqlite3): '
                    'a PNG of joint angles, wrist path, wrench, torques, loop periods and '
                    'link errors, and a CSV of the samples, per arm.')
    parser.add_argument('bag', help='rosbag2 directory (or a .mcap / .db3 file)')
    parser.add_argument('--calibration', metavar='YAML',
                        help='recompute joint angles and poses from the recorded pots with '
                             'this calibration (config/right_arm.yaml format) and compare')
    parser.add_argument('--out', metavar='DIR', default='.',
                        help='directory for the PNG and CSV files (default: .)')
    parser.add_argument('--arm-namespace', action='append', metavar='NS',
                        help="report only this namespace, e.g. /left ('/' for the root); "
                             'repeatable (default: every arm found)')
    parser.add_argument('--link-lengths', nargs=4, type=float, metavar=('L1', 'L2', 'L3', 'L4'),
                        help='link lengths (m) for the recalibrated poses (default: nominal)')
    return parser


def main(argv=None):
    """Write the report of a bag; return 0, or 1 when the bag or calibration is unusable."""
    args = _parser().parse_args(argv)
    started = time.monotonic()
    calibration = None
    try:
        if args.calibration:
            calibration = ArmCalibration.from_yaml(args.calibration)
        namespaces = None if not args.arm_namespace else [
            '' if ns.strip('/') == '' else '/' + ns.strip('/') for ns in args.arm_namespace]
        arms = read_arms(args.bag, namespaces, calibration)
    except (SessionError, CalibrationError) as error:
        print(f'kraft_master_report: {error}', file=sys.stderr)
        return 1
    lengths = kinematics.LinkLengths(*args.link_lengths) if args.link_lengths else None
    if calibration is not None and all(a.arm != calibration.arm for a in arms):
        print(f'kraft_master_report: {args.calibration} is for the {calibration.arm} arm; '
              f'the bag has {", ".join(a.arm for a in arms)}: not recalibrated',
              file=sys.stderr)
    bag = Path(args.bag).resolve()
    out = Path(args.out)
    print(f'{args.bag}:')
    try:
        out.mkdir(parents=True, exist_ok=True)
        for arm_data in arms:
            recalibration = (recalibrate(arm_data, calibration, lengths)
                             if calibration is not None and calibration.arm == arm_data.arm
                             else None)
            stem = '_'.join(filter(None, [bag.stem if bag.is_file() else bag.name,
                                          arm_data.namespace.strip('/').replace('/', '_')]))
            png, csv = out / f'{stem}_report.png', out / f'{stem}_samples.csv'
            write_csv(csv, arm_data, recalibration)
            draw(arm_data, recalibration, f'{bag.name} {arm_data.namespace or "/"} '
                 f'({arm_data.arm} arm)').savefig(png, dpi=80)
            for line in summary(arm_data, recalibration):
                print(line)
            print(f'  wrote {png} and {csv}')
    except OSError as error:
        print(f'kraft_master_report: cannot write the report: {error}', file=sys.stderr)
        return 1
    print(f'report took {time.monotonic() - started:.1f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
