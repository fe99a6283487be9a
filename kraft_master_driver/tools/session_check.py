# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The invariants of a recorded teleoperation session checked on its bag: kraft_master_report --check.

check_session(bag) reads, for each namespace that holds the driver's or the bridge's topics,
the arm's command (servo_cp or servo_cv), the arm's pose (measured_cp), the bridge's
operating_state, the master's torques (joint_states effort), its pot frames (pots), both
ports' energies (master_energy, slave_energy) and the diagnostics, and checks what
session_invariants.py holds them to. The faults are those given (a soak's schedule) and those
the recording shows: the bridge's FAULT and stale-pose holds, and gaps in the pot frames.
Times are the messages' receive times, in seconds of the bag's clock.
"""
import json
import math
import os
from typing import Any, Iterable, Mapping, NamedTuple, Optional

from kraft_master_driver.bag.common import (
    DIAGNOSTIC_ARRAY, JOINT_STATE, POSE_STAMPED, SessionError, TWIST_STAMPED, VECTOR3_STAMPED,
    WRENCH_STAMPED)
from kraft_master_driver.bag.decoding import TopicData
from kraft_master_driver.bag.reader import bag_topics, read_topics
from kraft_master_driver.core.teleoperation_settings import MAX_STEP, Settings
from kraft_master_driver.tools import session_invariants as invariants
from kraft_master_driver.tools.report_data import is_driver_status, node_statuses
from kraft_master_driver.tools.session_invariants import Fault, Limits, Series, Violation
import numpy as np

SIDES = ('master', 'arm', 'link', 'clock')
FORCE_UNTRUE_SIDES = ('arm', 'link')  # by default: faults that make the master's force untrue
TOPICS = {'servo_cp': POSE_STAMPED, 'servo_cv': TWIST_STAMPED, 'measured_cp': POSE_STAMPED,
          'operating_state': 'std_msgs/msg/String', 'joint_states': JOINT_STATE,
          'pots': JOINT_STATE, 'master_energy': VECTOR3_STAMPED,
          'slave_energy': VECTOR3_STAMPED, 'wrench': WRENCH_STAMPED}
# The bridge's own defaults where the bag does not hold its parameters.
DEFAULTS: dict[str, Any] = {
    'max_linear_speed': Settings().max_linear_speed, 'max_angular_speed':
    Settings().max_angular_speed, 'max_step_s': MAX_STEP, 'hold_tolerance': 0.002,
    'state_grace': 0.05, 'torque_zero_within': 0.110,
    'max_wrench_age': 0.1, 'torque_zero': 1e-9,
    'max_torque_step': 0.5, 'come_back_window': 0.2, 'wrench_timeout': 0.05,
    'force_scale': 1.0, 'contact_damping': 0.0, 'frame_tolerance': 2,
    'energy_tolerance': 0.003, 'energy_grace': 0.01, 'frame_gap': 0.1, 'passivity': None}
CHECKS = ('command steps', 'holds after a fault', 'torque zero after a fault',
          'torque steps as force comes back', 'pot frames all recorded', 'energy never generated')


class SessionCheck(NamedTuple):
    """The outcome: one line per violation (none: all hold), and a JSON-able summary."""

    violations: list[str]
    summary: dict[str, Any]


def limits_of(settings: Optional[Mapping[str, Any]]) -> tuple[Limits, Optional[bool]]:
    """Return the Limits and passivity (None: from the diagnostics) of settings over DEFAULTS."""
    merged = dict(DEFAULTS)
    unknown = sorted(set(settings or {}) - set(DEFAULTS))
    if unknown:
        raise ValueError(f'unknown setting {", ".join(unknown)}; known: {", ".join(DEFAULTS)}')
    merged.update(settings or {})
    return (Limits(**{name: merged[name] for name in Limits._fields}),
            merged['passivity'])


def faults_of(entries: Iterable[Mapping[str, Any]]) -> list[Fault]:
    """Return the Faults of dicts {kind, side, start, end, force_untrue?}; ValueError names one."""
    faults = []
    for number, entry in enumerate(entries, start=1):
        try:
            kind, side = str(entry['kind']), entry['side']
            start, end = float(entry['start']), float(entry['end'])
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f'fault {number}: needs kind, side, start and end ({error})'
                             ) from None
        if side not in SIDES or not start <= end or not math.isfinite(end):
            raise ValueError(f'fault {number}: side must be one of {", ".join(SIDES)} and '
                             f'start <= end, got {side!r}, {start}, {end}')
        untrue = bool(entry.get('force_untrue', side in FORCE_UNTRUE_SIDES))
        faults.append(Fault(kind, side, start, end, untrue))
    return faults


def read_faults(path: str | os.PathLike[str]) -> list[Fault]:
    """Return the faults of a JSON lines file, one dict a line; ValueError names the line."""
    entries = []
    with open(path, encoding='utf-8') as stream:
        for number, line in enumerate(stream, start=1):
            if line.strip():
                try:
                    entries.append(json.loads(line))
                except json.JSONDecodeError as error:
                    raise ValueError(f'{path} line {number}: not JSON: {error}') from None
    return faults_of(entries)


def _series(data: Optional[TopicData], *fields: str) -> Optional[Series]:
    if data is None or not len(data):
        return None
    stamp = data.fields.get('stamp')
    return Series(data.topic, data.log_time / 1e9, np.hstack([data.fields[f] for f in fields]),
                  None if stamp is None else stamp / 1e9, data.sequence)


class _Pair:
    """The topics of one namespace, decoded: the driver's, the bridge's and the arm's."""

    def __init__(self, namespace: str, data: Mapping[str, TopicData], end: float) -> None:
        def get(name: str) -> Optional[TopicData]:
            return data.get(f'{namespace}/{name}')
        self.namespace = namespace
        self.pose_command = _series(get('servo_cp'), 'position', 'orientation')
        self.twist_command = _series(get('servo_cv'), 'linear', 'angular')
        self.measured = _series(get('measured_cp'), 'position', 'orientation')
        self.effort = _series(get('joint_states'), 'effort')
        self.joints = _series(get('joint_states'), 'position', 'velocity')
        self.wrench = _series(get('wrench'), 'force', 'torque')
        self.pots = get('pots')
        self.master_energy = _series(get('master_energy'), 'vector')
        self.slave_energy = _series(get('slave_energy'), 'vector')
        states = get('operating_state')
        self.state_topic = f'{namespace}/operating_state'
        self.periods = ([] if states is None else invariants.state_periods(
            states.log_time / 1e9, [message.data for message in states.messages], end))
        diagnostics = {topic: data[topic] for topic in (f'{namespace}/diagnostics',
                                                        '/diagnostics') if topic in data}
        self.driver = node_statuses(namespace, diagnostics, is_driver_status)
        self.bridge = node_statuses(namespace, diagnostics, lambda values: 'state' in values)

    def recorded_faults(self, frame_gap: float) -> list[Fault]:
        """Return the faults the recording shows: FAULT, a late input's hold, no pot frames."""
        faults = [Fault('recorded: bridge FAULT', 'arm', p.start, p.end, True)
                  for p in self.periods if p.state == 'FAULT']
        faults += [Fault('recorded: master pose stale', 'link', p.start, p.end, True)
                   for p in self.periods if p.state == 'ENABLED' and
                   p.reason.startswith('holding: pose')]
        faults += [Fault('recorded: arm side late', 'arm', p.start, p.end, True)
                   for p in self.periods if p.state == 'ENABLED' and
                   p.reason.startswith('holding: measured')]
        frames = self.effort or _series(self.pots, 'position')
        if frames is not None:
            gaps = np.flatnonzero(np.diff(frames.t) > frame_gap)
            faults += [Fault('recorded: no pot frames', 'master', float(frames.t[i]),
                             float(frames.t[i + 1]), False) for i in gaps.tolist()]
        return faults


def _passivity(statuses: list, times: np.ndarray, setting: Optional[bool]) -> np.ndarray:
    """Return whether passivity was on at each time: the setting, or the node's last status."""
    if setting is not None or not statuses:
        return np.full(len(times), bool(setting))
    status_times = np.array([entry[0] / 1e9 for entry in statuses])
    on = np.array([entry[2].get('passivity') == 'on' for entry in statuses])
    return on[np.maximum(np.searchsorted(status_times, times, side='right') - 1, 0)]


def _check_pair(pair: _Pair, faults: list[Fault], limits: Limits, passivity: Optional[bool],
                checked: dict[str, dict[str, Any]]) -> list[Violation]:
    """Run every check that the namespace's topics allow; count in `checked` where and what."""
    found: list[Violation] = []
    where = pair.namespace or '/'

    def ran(check: str, violations: list[Violation]) -> None:
        if where not in checked[check]['ran_on']:
            checked[check]['ran_on'].append(where)
        checked[check]['violations'] += len(violations)
        found.extend(violations)

    if pair.pose_command is not None:
        ran(CHECKS[0], invariants.command_steps(pair.pose_command, pair.measured, limits))
    if pair.twist_command is not None:
        ran(CHECKS[0], invariants.twist_limits(pair.twist_command, limits))
    command = pair.pose_command or pair.twist_command
    if command is not None and pair.periods:
        ran(CHECKS[1], invariants.holds(pair.periods, command, command is pair.twist_command,
                                        limits))
    if pair.effort is not None:
        ran(CHECKS[2], invariants.torque_zero(faults, pair.effort, limits, pair.wrench))
        # Force comes back at a fault's end, and at the enable that ends a FAULT after it.
        recoveries = {f.end: f for f in faults}
        for fault in faults:
            for period in pair.periods:
                if period.state == 'FAULT' and period.start >= fault.start:
                    recoveries.setdefault(period.end, fault._replace(end=period.end))
        ran(CHECKS[3], invariants.torque_steps(list(recoveries.values()), pair.effort, limits,
                                               pair.joints, pair.wrench))
    counts = [(log / 1e9, stamp, int(values['pot frames published']))
              for log, stamp, values in pair.driver if 'pot frames published' in values]
    if pair.pots is not None and len(pair.pots) and counts:
        lost_found, _ = invariants.frames_lost(pair.pots.fields['stamp'], counts,
                                               pair.pots.topic, limits)
        ran(CHECKS[4], lost_found)
    for own, credit, statuses, port in (
            (pair.master_energy, pair.slave_energy, pair.driver, 'master'),
            (pair.slave_energy, pair.master_energy, pair.bridge, 'slave')):
        if own is not None and credit is not None:
            on = _passivity(statuses, own.t, passivity)
            if on.any():
                ran(CHECKS[5], invariants.energy_generated(own, credit, on, port, limits)[0])
            else:
                checked[CHECKS[5]]['skipped'] = f'passivity off at the {port} port'
    return found


def _first_at(times: np.ndarray, after: float) -> Optional[float]:
    index = int(np.searchsorted(times, after))
    return float(times[index]) if index < len(times) else None


def _times(fault: Fault, pair: _Pair, limits: Limits) -> tuple[Optional[float], Optional[float]]:
    """Return (time to safe, time to recovery) of a fault, s, from what the pair recorded."""
    safe = []
    if fault.force_untrue and pair.effort is not None:
        zero = np.max(np.abs(pair.effort.values), axis=1, initial=0.0) <= limits.torque_zero
        safe.append(_first_at(pair.effort.t[zero], fault.start))
    if fault.side != 'master' and pair.periods:
        held = [p.start for p in pair.periods if p.start >= fault.start and
                p.start <= fault.end + limits.state_grace and (p.state != 'ENABLED' or p.reason)]
        safe.append(held[0] if held else None)
    known = [t for t in safe if t is not None]
    to_safe = max(known) - fault.start if known and len(known) == len(safe) else None
    frames = pair.effort or _series(pair.pots, 'position')
    back = [None if frames is None else _first_at(frames.t, fault.end)]
    at_start = [p for p in pair.periods if p.start <= fault.start < p.end]
    if at_start and at_start[0].state == 'ENABLED' and not at_start[0].reason:
        # The bridge followed when the fault came: recovered when it follows again.
        following = [max(p.start, fault.end) for p in pair.periods
                     if p.end > fault.end and p.state == 'ENABLED' and not p.reason]
        back.append(following[0] if following else None)
    to_recovery = (max(back) - fault.end  # type: ignore[type-var]  # None excluded
                   if all(t is not None for t in back) else None)
    return to_safe, to_recovery


def _figures(values: list[Optional[float]]) -> dict[str, Optional[float]]:
    known = [1e3 * v for v in values if v is not None]
    if not known:
        return {'max': None, 'p99': None}
    return {'max': round(max(known), 1), 'p99': round(float(np.percentile(known, 99)), 1)}


def check_session(bag_path: str | os.PathLike[str],
                  faults: Optional[Iterable[Mapping[str, Any]]] = None,
                  settings: Optional[Mapping[str, Any]] = None) -> SessionCheck:
    """
    Check the invariants of the session recorded in `bag_path`; return a SessionCheck.

    faults: dicts {kind, side (master, arm, link or clock), start, end (s of the bag's
    clock)}, optionally force_untrue (default: true for arm and link); settings: bounds over
    DEFAULTS. Raises SessionError for an unreadable bag, ValueError for bad faults or settings.
    """
    limits, passivity = limits_of(settings)
    given = faults_of(faults or [])
    types = bag_topics(bag_path)
    namespaces = sorted({topic.rpartition('/')[0] for topic in types
                         if topic.rpartition('/')[2] in TOPICS})
    if not namespaces:
        raise SessionError(f'{bag_path}: none of the session topics '
                           f'({", ".join(TOPICS)}) in the bag')
    wanted = [f'{ns}/{name}' for ns in namespaces for name, msgtype in TOPICS.items()
              if types.get(f'{ns}/{name}', (None,))[0] == msgtype]
    wanted += [t for ns in namespaces for t in (f'{ns}/diagnostics', '/diagnostics')
               if types.get(t, (None,))[0] == DIAGNOSTIC_ARRAY]
    data = read_topics(bag_path, sorted(set(wanted)))
    ends = [float(d.log_time[-1]) / 1e9 for d in data.values() if len(d)]
    starts = [float(d.log_time[0]) / 1e9 for d in data.values() if len(d)]
    end = max(ends, default=0.0)
    checked: dict[str, dict[str, Any]] = {
        check: {'ran_on': [], 'violations': 0} for check in CHECKS}
    found: list[Violation] = []
    timings: dict[str, dict[str, Any]] = {}
    for namespace in namespaces:
        pair = _Pair(namespace, data, end)
        pair_faults = given + pair.recorded_faults(DEFAULTS['frame_gap'])
        found += _check_pair(pair, pair_faults, limits, passivity, checked)
        for fault in pair_faults:
            kind = timings.setdefault(fault.kind, {'side': fault.side, 'count': 0, 'safe': [],
                                                   'recovery': []})
            to_safe, to_recovery = _times(fault, pair, limits)
            kind['count'] += 1
            kind['safe'].append(to_safe)
            kind['recovery'].append(to_recovery)
    found.sort()
    lines = [violation.line for violation in found]
    summary = {
        'bag': str(bag_path), 'namespaces': [ns or '/' for ns in namespaces],
        'start_s': round(min(starts, default=0.0), 3), 'end_s': round(end, 3),
        'settings': {**DEFAULTS, **(settings or {})},
        'faults': {name: {'side': kind['side'], 'count': kind['count'],
                          'time_to_safe_ms': _figures(kind['safe']),
                          'time_to_recovery_ms': _figures(kind['recovery']),
                          'not_recovered': sum(t is None for t in kind['recovery'])}
                   for name, kind in sorted(timings.items())},
        'checks': {check: {'ran_on': outcome['ran_on'], 'violations': outcome['violations']}
                   if outcome['ran_on'] else 'not checked: ' + outcome.get(
                       'skipped', 'its topics are not in the bag')
                   for check, outcome in checked.items()},
        'violations': lines}
    return SessionCheck(lines, summary)
