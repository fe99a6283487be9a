# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The data of kraft_master_report: a session bag read into whole arrays, one ArmData per arm.

Each namespace that holds joint_states, pots or pose is an arm. Its topics are joined on the
header stamp they share, and its diagnostics are picked from <namespace>/diagnostics or
/diagnostics by the node's name. Also here: the joint angles and poses recomputed from the pots
with another calibration, and the loop periods and diagnostics series that the tables
(report_tables.py) and the figure (report_plots.py) are made of.
"""
import math
import os
from typing import Iterable, Mapping, NamedTuple, Sequence

from kraft_master_driver.bag.common import DRIVER_TOPICS, SessionError
from kraft_master_driver.bag.decoding import TopicData
from kraft_master_driver.bag.reader import bag_topics, read_topics
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration
from kraft_master_driver.core.rotations import rotations_to_quaternions
import numpy as np

ARM_TOPICS = ('joint_states', 'pose', 'pots', 'wrench', 'diagnostics')
STATE_TOPICS = ('joint_states', 'pots', 'pose')  # one of them makes a namespace an arm
# Link counters that are not errors: progress, and what the driver did to commands.
LINK_NOT_ERRORS = ('cycles', 'replies', 'clamped_commands', 'nonfinite_commands',
                   'zero_commands', 'low_latency_failures')
LOOP_COUNTERS = ('late cycles', 'missed cycles')
ROUND_TRIP_KEYS = tuple(f'link round trip {label} (ms)' for label in ('median', 'p99', 'max'))

# (receive time ns, {key: value}) of each status of one driver, in time order
DiagnosticsLog = list[tuple[int, dict[str, str]]]


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
    diagnostics: DiagnosticsLog  # of this driver's status
    missing: list  # topics absent from the bag
    notes: list  # other faults found: malformed messages, wrong types


class Recalibration(NamedTuple):
    """Joint angles and wrist poses recomputed from the raw pots with another calibration."""

    source: str
    position: np.ndarray  # (N, 6) rad
    wrist: np.ndarray  # (N, 3) m
    orientation: np.ndarray  # (N, 4)


# -- reading ---------------------------------------------------------------------------------


def find_namespaces(topics: Iterable[str]) -> list[str]:
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


def node_statuses(namespace, topics, belongs):
    """
    Return (receive time, stamp, {key: value}) of one node's status in `namespace`, in order.

    topics maps each diagnostics topic read ('<namespace>/diagnostics', '/diagnostics') to
    its TopicData; times are int ns, the stamp the array's header stamp. A status is the
    node's when belongs({key: value}) is true and its name carries the node's namespace, or a
    bare node name on the namespace's own diagnostics topic.
    """
    entries = []
    for topic, data in topics.items():
        for log_time, message in zip(data.log_time.tolist(), data.messages):
            stamp = message.header.stamp
            for status in message.status:
                values = {pair.key: pair.value for pair in status.values}
                owner = _status_namespace(status.name)
                if belongs(values) and (
                        (owner or '/') == (namespace or '/') or
                        (owner is None and topic == f'{namespace}/diagnostics')):
                    entries.append((log_time, stamp.sec * 1_000_000_000 + stamp.nanosec,
                                    values))
                    break
    return sorted(entries, key=lambda entry: entry[0])


def is_driver_status(values):
    """Return whether a status's values are the driver's: it has link counters."""
    return any(key.startswith('link ') for key in values)


def _diagnostics(namespace, topics):
    """Return (receive time, {key: value}) of the driver's status in `namespace`, in order."""
    return [(log_time, values) for log_time, _, values
            in node_statuses(namespace, topics, is_driver_status)]


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


def diagnostics_topics(namespace: str) -> list[str]:
    """Return where the driver in `namespace` may publish diagnostics: its own, /diagnostics."""
    return list(dict.fromkeys([f'{namespace}/diagnostics', '/diagnostics']))


def arm_topics(namespace: str) -> list[str]:
    """Return the topics read for the driver in `namespace`."""
    return [f'{namespace}/{name}' for name in ARM_TOPICS if name != 'diagnostics'] + (
        diagnostics_topics(namespace))


def assemble(namespace: str, data: Mapping[str, TopicData],
             topics: Mapping[str, tuple[str, int]],
             calibration: ArmCalibration | None = None) -> ArmData:
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


def read_arms(bag: str | os.PathLike, namespaces: Sequence[str] | None = None,
              calibration: ArmCalibration | None = None) -> list[ArmData]:
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


def recalibrate(arm_data: ArmData, calibration: ArmCalibration,
                lengths: kinematics.LinkLengths | None = None) -> Recalibration:
    """Recompute joint angles and wrist poses from the recorded pots with `calibration`."""
    position = calibration.pots_to_joints(arm_data.pots)
    wrist = np.full((len(position), 3), np.nan)
    orientation = np.full((len(position), 4), np.nan)
    valid = np.flatnonzero(np.all(np.isfinite(position), axis=1))
    if valid.size:
        poses = kinematics.forward(position[valid], arm_data.arm, lengths)
        wrist[valid] = poses[:, :3, 3]
        orientation[valid] = rotations_to_quaternions(poses[:, :3, :3])
    return Recalibration(calibration.source, position, wrist, orientation)


def loop_periods(stamp: np.ndarray) -> np.ndarray:
    """Return the periods (s) between consecutive samples."""
    return np.diff(stamp) / 1e9


def diagnostics_series(diagnostics: DiagnosticsLog, keys: Iterable[str]
                       ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
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


def link_errors(diagnostics: DiagnosticsLog) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Return (times ns, {counter: values}) of the link error counters that ever rose."""
    keys = sorted({key for _, values in diagnostics for key in values
                   if key.startswith('link ') and not key.endswith('(ms)') and
                   key.removeprefix('link ') not in LINK_NOT_ERRORS})
    times, series = diagnostics_series(diagnostics, keys)
    return times, {key.removeprefix('link '): values for key, values in series.items()
                   if np.nanmax(values, initial=0.0) > 0}


def last_values(series: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Return {key: the last finite value} of diagnostics series (absent if none)."""
    return {key: values[np.isfinite(values)][-1] for key, values in series.items()
            if np.isfinite(values).any()}
