#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Force reflection across a delaying, lossy link: holding contact with the stiff wall.

One row per round trip, loss and passivity setting, each a fresh session of
test/harness/remote_session.py (two hosts as network namespaces joined by a veth pair; the
driver and the link emulator on one, the bridge and the simulated arm behind it on the other,
the simulated device in this process on TCP): the operator pushes the master through the arm's
wall, holds, releases.
Figures, no asserts: a table and JSON (--json).
"""
import argparse
import json
import pathlib
import platform
import sys
import tempfile

from harness import remote_session as session
from harness.driver import colcon_build

ROUND_TRIPS_MS = (0, 20, 50, 100, 250, 500)
LOSSES = (0.0, 0.01, 0.1)

COLUMNS = (('past mm', 'past_mm', '{:.0f}'), ('rtt ms', 'round_trip_ms', '{:.0f}'),
           ('loss %', 'loss_pct', '{:.0f}'),
           ('passivity', 'passivity', '{}'), ('master p-p mm', 'master_pp_mm', '{:.2f}'),
           ('master past mm', 'master_depth_mm', '{:.2f}'),
           ('slave pen. mm', 'slave_penetration_mm', '{:.2f}'),
           ('channel E J', 'energy_generated_j', '{:+.4f}'),
           ('F slave N', 'force_slave_n', '{:.2f}'), ('F felt N', 'force_felt_n', '{:.2f}'),
           ('felt/slave', 'felt_ratio', '{:.3f}'), ('drift mm', 'drift_mm', '{:.2f}'),
           ('pose->slave p99 ms', 'pose_to_slave_p99_ms', '{:.2f}'),
           ('wrench->driver p99 ms', 'wrench_to_driver_p99_ms', '{:.2f}'))


def main(argv=None):
    """Run every row (or those chosen), print the table, write JSON if asked."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--round-trips', type=float, nargs='+', default=ROUND_TRIPS_MS)
    parser.add_argument('--losses', type=float, nargs='+', default=LOSSES,
                        help='fractions, e.g. 0 0.01 0.1')
    parser.add_argument('--passivity', choices=('off', 'on', 'both'), default='both')
    parser.add_argument('--arm', choices=tuple(session.ARMS), default='point-mass',
                        help='the simulated arm: the point mass and its wall, or the MuJoCo Panda '
                        'and its table')
    parser.add_argument('--past', type=float, nargs='+', default=[1e3 * session.PAST],
                        help="how far the operator's hand aims past the arm's surface (mm)")
    parser.add_argument('--arm-set', nargs='+', default=[], metavar='NAME:=VALUE',
                        help="parameters of the arm's node, e.g. translational_stiffness:=5000 "
                        "(the bridge's arm_stiffness follows it)")
    parser.add_argument('--bridge-set', nargs='+', default=[], metavar='NAME:=VALUE',
                        help='parameters of the bridge, e.g. slave_port_force:=sent')
    parser.add_argument('--driver-set', nargs='+', default=[], metavar='NAME:=VALUE',
                        help='parameters of the driver, e.g. passivity_damping:=5.0')
    parser.add_argument('--json', type=pathlib.Path, help='write the rows here')
    args = parser.parse_args(argv)
    modes = {'off': (False,), 'on': (True,), 'both': (False, True)}[args.passivity]
    rows = []
    with tempfile.TemporaryDirectory(prefix='kmd_delay_') as workdir:
        prefix = colcon_build(pathlib.Path(workdir))
        print(' | '.join(title for title, _, _ in COLUMNS), flush=True)
        arm_parameters = [text.split(':=', 1) for text in args.arm_set]
        bridge_parameters = [('arm_stiffness', value) for name, value in arm_parameters
                             if name == 'translational_stiffness']
        bridge_parameters += [text.split(':=', 1) for text in args.bridge_set]
        driver_parameters = [text.split(':=', 1) for text in args.driver_set]
        for seed, (past, round_trip, loss, passivity) in enumerate(
                (d, r, s, p) for d in args.past for r in args.round_trips for s in args.losses
                for p in modes):
            row = {'past_mm': past, 'round_trip_ms': round_trip, 'loss_pct': 100.0 * loss,
                   'passivity': 'on' if passivity else 'off',
                   **session.run_row(prefix, round_trip, loss, passivity, seed, args.arm,
                                     past / 1e3, arm_parameters, bridge_parameters,
                                     driver_parameters)}
            rows.append(row)
            print(' | '.join(form.format(row[key]) for _, key, form in COLUMNS), flush=True)
    if args.json:
        args.json.write_text(json.dumps({
            'machine': platform.node(), 'arm': args.arm, 'arm_set': args.arm_set,
            'bridge_set': args.bridge_set, 'driver_set': args.driver_set,
            'slave': session.SLAVE, 'bridge': session.BRIDGE,
            'wall_below_m': session.WALL_BELOW, 'hold_s': session.HOLD,
            'window_s': session.WINDOW, 'rows': rows}, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
