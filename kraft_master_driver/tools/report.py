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

This module is the command line: report_data.py reads the bag, report_tables.py writes the
CSV and the summary, and report_plots.py draws the figure.
"""
import argparse
from pathlib import Path
import sys
import time

from kraft_master_driver.bag.common import SessionError
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration, CalibrationError
from kraft_master_driver.tools.report_data import read_arms, recalibrate
from kraft_master_driver.tools.report_plots import draw
from kraft_master_driver.tools.report_tables import summary, write_csv


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
