#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Session soak: driver, bridge, MuJoCo Panda and the link between them, under faults at both ends.

The driver runs on the simulated master (its operator hand at a task: moves, touches of the
table, holds), the bridge and the Panda on another DDS domain, the link between them (--link:
the link emulator, or a Zenoh link on each site paired with mutual TLS over 127.0.0.1), and a
recorder (the project's Recorder) on both; the operator enables the bridge and clutches now
and then. On a schedule drawn from --seed and printed at the start, it injects faults on both
ends (test/harness/soak_faults.py): the master's device and wrench input, the wrist sensor,
the arm's controller (stalled, killed and restarted), the bridge (killed and restarted), and
with the emulator the link (blackout, delay step, loss burst) and a clock's stamps, with Zenoh
a restart of either site's link (killed, started again after the fault). At the end every
process is stopped and what was left behind is listed, the faults are written as JSON lines and
the recorded session is checked by kraft_master_driver.tools.session_check. The summary (JSON
and a table) has the faults by kind with their time to safe and to recovery (max and p99),
the invariants' violations, the processes' RSS slopes and exit codes, and a plot of
one fault of each kind. Exit 1 if anything failed. `make teleop-soak` runs it.
"""
import argparse
import json
import os
import pathlib
import platform
import sys
import time

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / 'test')]

from harness.soak_site import DRIVER, LINKS, MAX_WRENCH_AGE_S  # noqa: E402  (test/ first)
from harness.teleop_soak import Soak  # noqa: E402
import numpy as np  # noqa: E402

RSS_SLOPE_LIMIT = 100.0  # KiB/min after warm-up: above it, a process's memory is not flat
PRESS_N = 5.0  # N: the bridge's wrench at least this, for PRESS_S or more, is a press
PRESS_S = 0.5
NUMB_NM = 0.05  # N*m: a press whose master torque stays below this 90 % of the time is numb
FAULT_MARGIN_S = 1.0  # s around a fault: a press there may be numb by the rules


def check(soak, bag):
    """Return the checker's (violations, summary), or a note that it could not run."""
    try:
        from kraft_master_driver.tools.session_check import check_session
    except ImportError as error:
        return None, {'not checked': f'no session checker in this checkout ({error})'}
    result = check_session(bag, faults=soak.faults, settings={
        'passivity': True, 'max_wrench_age': MAX_WRENCH_AGE_S,
        'contact_damping': DRIVER['contact_damping']})
    return result.violations, result.summary


def numb_presses(bag, faults):
    """
    Return (presses, the receive times of those not felt) away from the faults.

    A press: the wrench the bridge sends at PRESS_N or more for PRESS_S or more. Felt: the
    master's largest joint torque at NUMB_NM or more for over a tenth of it.
    """
    from kraft_master_driver.bag.reader import read_topics
    data = read_topics(bag, ['/wrench', '/joint_states'])
    if '/wrench' not in data or '/joint_states' not in data:
        return 0, []
    wrench, effort = data['/wrench'], data['/joint_states']
    t = wrench.log_time / 1e9
    pressing = np.linalg.norm(wrench.fields['force'], axis=1) >= PRESS_N
    edges = np.flatnonzero(np.diff(np.r_[0, pressing.astype(int), 0]))
    torque_t = effort.log_time / 1e9
    torque = np.max(np.abs(effort.fields['effort']), axis=1, initial=0.0)
    presses, numb = 0, []
    for first, after in zip(edges[::2], edges[1::2]):
        start, end = t[first], t[after - 1]
        if end - start < PRESS_S or any(
                start < f['end'] + FAULT_MARGIN_S and end > f['start'] - FAULT_MARGIN_S
                for f in faults):
            continue
        presses += 1
        felt = torque[(torque_t >= start) & (torque_t <= end)]
        if not felt.size or np.mean(felt >= NUMB_NM) <= 0.1:
            numb.append(round(float(start), 3))
    return presses, numb


def percentile_ms(values, q):
    """Return the q-th percentile of `values` (s) in ms, None if there are none."""
    known = [1e3 * v for v in values if v is not None]
    return round(float(np.percentile(known, q)), 1) if known else None


def summarise(soak, seconds, violations, checked, presses):
    """Return the run's figures as a JSON-able dict; presses: numb_presses()'s."""
    kinds = {}
    for entry in soak.faults:
        kinds.setdefault(entry['kind'], []).append(entry)
    by_kind = {}
    for name, entries in kinds.items():
        follow = [e['following_again_s'] for e in entries]
        timing = checked.get('faults', {}).get(name, {}) if isinstance(checked, dict) else {}
        by_kind[name] = {
            'side': entries[0]['side'], 'count': len(entries),
            'lasted_s_max': round(max(e['end'] - e['start'] for e in entries), 3),
            'time_to_safe_ms': timing.get('time_to_safe_ms'),
            'time_to_recovery_ms': timing.get('time_to_recovery_ms'),
            'following_again_ms': {'max': percentile_ms(follow, 100),
                                   'p99': percentile_ms(follow, 99)},
            'not_followed_again': sum(f is None for f in follow)}
    rss = soak.rss_slopes()
    return {
        'seed': soak.seed, 'duration_s': soak.duration, 'link': soak.link,
        'seconds': round(seconds, 1),
        'faults_injected': len(soak.faults), 'kinds': len(by_kind), 'faults': by_kind,
        'violations': violations, 'checker': checked,
        'presses_away_from_faults': presses[0], 'numb_presses': presses[1],
        'rss': rss, 'rss_not_flat': sorted(
            f'{name} (pid {run["pid"]}): {run["slope_kib_per_min"]} KiB/min'
            for name, runs in rss.items() for run in runs
            if (run['slope_kib_per_min'] or 0.0) > RSS_SLOPE_LIMIT),
        'exit_codes': getattr(soak, 'exit_codes', {}),
        'leftovers': getattr(soak, 'leftovers', ['the run did not get to its end']),
        'notes': soak.notes,
        'machine': {'platform': platform.platform(), 'cpus': os.cpu_count(),
                    'load_average_at_end': [round(v, 2) for v in os.getloadavg()]},
    }


def passed(figures):
    """Return whether it passed: no violation, nothing left, memory flat, followed and felt."""
    return (figures['violations'] == [] and not figures['leftovers'] and not figures['notes']
            and not figures['rss_not_flat'] and not figures['numb_presses'])


def cell(figure):
    """Return 'max / p99' of a {max, p99} dict in ms, '-' where unknown."""
    if not figure or figure.get('max') is None:
        return '-'
    return f'{figure["max"]:.0f} / {figure["p99"]:.0f}'


def table(figures):
    """Return a Markdown table of the faults by kind (doc/safety.md)."""
    lines = ['| fault | side | n | longest (s) | to safe, max / p99 (ms) | '
             'to recovery, max / p99 (ms) | following again, max / p99 (ms) |',
             '|---|---|---|---|---|---|---|']
    for name, kind in sorted(figures['faults'].items()):
        lines.append(f'| {name} | {kind["side"]} | {kind["count"]} | {kind["lasted_s_max"]:.2f} '
                     f'| {cell(kind["time_to_safe_ms"])} | {cell(kind["time_to_recovery_ms"])} '
                     f'| {cell(kind["following_again_ms"])} |')
    return '\n'.join(lines)


def print_summary(figures):
    """Print the table and the verdicts."""
    print(f'\nteleop soak: {figures["seconds"]:.0f} s, seed {figures["seed"]}, link '
          f'{figures["link"]}, {figures["faults_injected"]} faults of {figures["kinds"]} kinds')
    print(table(figures))
    violations = figures['violations']
    print('invariant violations: ' + ('none' if violations == [] else
                                      'not checked' if violations is None else
                                      f'{len(violations)}'))
    for line in (violations or [])[:50]:
        print(f'  {line}')
    numb = figures['numb_presses']
    print(f'presses away from faults: {figures["presses_away_from_faults"]}, not felt: '
          + (', '.join(f'{t:.3f}' for t in numb) if numb else 'none'))
    for key in ('leftovers', 'notes', 'rss_not_flat'):
        print(f'{key}: ' + ('none' if not figures[key] else '; '.join(figures[key])))
    print(f'exit codes at SIGINT: {figures["exit_codes"]}')
    print(f'load average at the end: {figures["machine"]["load_average_at_end"]}')


def main(argv=None):
    """Run the soak; write the faults, the summary and the figure; return 0 if it passed."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--duration', type=float, default=1800.0,
                        help='seconds of faults and operation (default 1800)')
    parser.add_argument('--seed', type=int, default=0, help='seed of the schedule (default 0)')
    parser.add_argument('--link', choices=LINKS, default='emulator',
                        help='between the sites: the link emulator (default) or two Zenoh '
                             'links with mutual TLS')
    parser.add_argument('--longest-fault', type=float, default=float('inf'),
                        help='cut every drawn fault duration to this (s)')
    parser.add_argument('--out', type=pathlib.Path,
                        help='directory of the bag, logs, faults and summary '
                             '(default build/teleop_soak/<time>)')
    parser.add_argument('--figure', type=pathlib.Path,
                        help='plot one fault of each kind into this PNG '
                             '(default: figure.png in --out)')
    args = parser.parse_args(argv)
    out = args.out or REPO / 'build' / 'teleop_soak' / time.strftime('%Y%m%d-%H%M%S')
    out.mkdir(parents=True, exist_ok=True)
    figure = args.figure or out / 'figure.png'
    load = [round(v, 2) for v in os.getloadavg()]
    print(f'load average at the start: {load}; writing to {out}')
    soak = Soak(out, args.seed, args.duration, args.longest_fault, args.link)
    seconds = soak.run()
    faults_path = out / 'faults.jsonl'
    soak.write_faults(faults_path)
    violations, checked = check(soak, soak.site.bag)
    presses = numb_presses(soak.site.bag, soak.faults)
    figures = summarise(soak, seconds, violations, checked, presses)
    (out / 'summary.json').write_text(json.dumps(figures, indent=2, default=str))
    (out / 'table.md').write_text(table(figures) + '\n')
    print_summary(figures)
    from soak_figure import draw  # beside this script
    draw(soak.site.bag, soak.faults, figure)
    print(f'figure: {figure}')
    print(f'summary: {out / "summary.json"}')
    return 0 if passed(figures) else 1


if __name__ == '__main__':
    sys.exit(main())
