#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Tapping the table on the MuJoCo Panda, direct force against the contact model, in simulated time.

Each cell is one session of test/harness/teleop_loop.py (the driver's, the bridge's and the
Panda's own classes stepped together every millisecond, the master read through whole pot
counts, 1 % loss and 5 ms of jitter each way): five touches of the table, each aiming 15 mm
past it and back up 20 mm, with the driver's force_mode direct, model or auto; the table's
stiffness 1000, 2500 or 5000 N/m behind the Panda's 1000 N/m; and a table that moves 10 mm
down before the third touch. Per cell, over the touches the targets are for (from the second;
on the moved table from the fourth): how far past the table the master stopped (the largest),
and how far that is from where a wall of the stiffness possible (the arm's in series with the
table's, clipped to the renderable wall) at the table's place would hold the table's force, the
peak-to-peak in the hold, the stiffness felt over the possible, the force felt over the
table's, the largest step of the force felt in one millisecond; the largest force felt while
the master is above the table (drag, or a contact of the past) from the second touch on, but on
the moved table's
first touch, whose force felt above the table is the stale model's, apart; of the first touch
the table's largest force and how long after the arm the master first felt 1 N. Figures, no
asserts; the same on a busy machine. `PYTHONPATH=test python -m benchmarks.tapping`.
"""
import argparse
import json
import math
import pathlib
import sys

from harness.teleop_loop import Session, Tapping, tapping_figures

COLUMNS = (('rtt ms', 'round_trip_ms', '{:.0f}'), ('table N/m', 'table_stiffness', '{:.0f}'),
           ('mode', 'force_mode', '{}'), ('moved', 'moved', '{}'),
           ('possible N/m', 'possible', '{:.0f}'), ('stop mm', 'stop_mm', '{:.1f}'),
           ('stop error mm', 'stop_error_mm', '{:.2f}'), ('p-p mm', 'pp_mm', '{:.2f}'),
           ('felt/possible', 'stiffness_ratio', '{:.2f}'),
           ('felt/table', 'force_ratio', '{:.2f}'), ('step N', 'force_step', '{:.2f}'),
           ('drag N', 'drag', '{:.2f}'), ('moved: stale N', 'stale_force', '{:.1f}'),
           ('1st: table N', 'first_table_force', '{:.1f}'),
           ('1st: felt after ms', 'first_felt_after_ms', '{:.0f}'))


def row(session, tapping):
    """Return one cell's figures, in the table's units."""
    touches, run = tapping_figures(session, tapping)
    return {'round_trip_ms': session.round_trip_ms, 'table_stiffness': session.table_stiffness,
            'force_mode': session.force_mode, 'moved_before': tapping.moved_before,
            **summary(touches, run, tapping.moved_before), 'touches': touches, 'run': run}


def summary(touches, run, moved_before):
    """Return the table's figures of a cell's touches and run."""
    counted = touches[(moved_before + 1 if moved_before else 2) - 1:]
    possible = run['possible_stiffness']
    drags = [touch['drag'] for number, touch in enumerate(touches, 1)
             if number > 1 and number != moved_before and not math.isnan(touch['drag'])]
    return {
        'moved': 'yes' if moved_before else 'no', 'possible': possible,
        'stop_mm': 1e3 * max(t['master_past'] for t in counted),
        'stop_error_mm': 1e3 * max(abs(t['master_past'] - t['table_force'] / possible)
                                   for t in counted),
        'pp_mm': 1e3 * max(t['master_pp'] for t in counted),
        'stiffness_ratio': min(t['felt_stiffness'] for t in counted) / possible,
        'force_ratio': min(t['felt_force'] / t['table_force'] for t in counted),
        'force_step': max(t['force_step'] for t in counted),
        'drag': max(drags) if drags else math.nan,
        'stale_force': touches[moved_before - 1]['drag'] if moved_before else math.nan,
        'first_table_force': touches[0]['max_table_force'],
        'first_felt_after_ms': 1e3 * (run['master_first_force'] - run['arm_first_force'])}


def main(argv=None):
    """Run the grid (or the cells chosen), print the table, write JSON if asked."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--round-trips', type=float, nargs='+',
                        default=(0, 100, 250, 500, 1000))
    parser.add_argument('--tables', type=float, nargs='+', default=(1000, 2500, 5000),
                        help="the table's stiffness (N/m)")
    parser.add_argument('--modes', nargs='+', default=('direct', 'model', 'auto'),
                        choices=('direct', 'model', 'auto'))
    parser.add_argument('--moved', choices=('no', 'yes', 'both'), default='both',
                        help='the table moves 10 mm down before the third touch')
    parser.add_argument('--json', type=pathlib.Path, help='write the rows here')
    parser.add_argument('--table-of', type=pathlib.Path,
                        help='print the table of the rows a run wrote with --json; run none')
    args = parser.parse_args(argv)
    if args.table_of:
        print(' | '.join(title for title, _, _ in COLUMNS))
        for cell in json.loads(args.table_of.read_text())['rows']:
            cell.update(summary(cell['touches'], cell['run'], cell['moved_before']))
            print(' | '.join(form.format(cell[key]) for _, key, form in COLUMNS))
        return 0
    moves = {'no': (0,), 'yes': (3,), 'both': (0, 3)}[args.moved]
    print(' | '.join(title for title, _, _ in COLUMNS), flush=True)
    rows = []
    for moved in moves:
        for round_trip in args.round_trips:
            for table in args.tables:
                for mode in args.modes:
                    session = Session(round_trip, 0.01, jitter_ms=5.0, pot_counts=True,
                                      force_mode=mode, table_stiffness=table)
                    rows.append(row(session, Tapping(moved_before=moved)))
                    print(' | '.join(form.format(rows[-1][key]) for _, key, form in COLUMNS),
                          flush=True)
    if args.json:
        args.json.write_text(json.dumps({'rows': rows}, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
