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

With --check it draws nothing: it checks the invariants of a teleoperation session on the
bag (session_check.py), prints one line per violation and a table of the faults, and exits 1
on any violation, 0 when all hold.

This module is the command line: report_data.py reads the bag, report_tables.py writes the
CSV and the summary, and report_plots.py draws the figure.
"""
import argparse
import json
from pathlib import Path
import sys
import time

from kraft_master_driver.bag.common import SessionError
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration, CalibrationError
from kraft_master_driver.tools.report_data import read_arms, recalibrate
from kraft_master_driver.tools.report_plots import draw
from kraft_master_driver.tools.report_tables import summary, write_csv
from kraft_master_driver.tools.session_check import check_session, read_faults


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
    check = parser.add_argument_group(
        'checking a teleoperation session (doc/safety.md)')
    check.add_argument('--check', action='store_true',
                       help="check the session's invariants instead of drawing: one line per "
                            'violation, a table of the faults; exit 1 on any violation')
    check.add_argument('--faults', metavar='JSONL',
                       help='with --check: the faults injected, one JSON object a line: kind, '
                            "side (master, arm, link, clock), start, end (s, the bag's clock)")
    check.add_argument('--json', metavar='OUT', help='with --check: write the summary here')
    return parser


def _milliseconds(value):
    return '-' if value is None else f'{value:.1f}'


def check(args):
    """Check the session in args.bag; print violations and the table; return the exit code."""
    try:
        faults = None if args.faults is None else [
            fault._asdict() for fault in read_faults(args.faults)]
        result = check_session(args.bag, faults)
    except (SessionError, ValueError, OSError) as error:
        print(f'kraft_master_report: {error}', file=sys.stderr)
        return 1
    for line in result.violations:
        print(line)
    outcome = result.summary
    print(f'{args.bag}: {", ".join(outcome["namespaces"])}, {outcome["start_s"]:.3f} to '
          f'{outcome["end_s"]:.3f} s')
    print(f'  {"fault":<36} {"side":<6} {"n":>4} {"to safe max/p99 (ms)":>21} '
          f'{"to recovery max/p99 (ms)":>25}')
    for kind, figures in outcome['faults'].items():
        safe, back = figures['time_to_safe_ms'], figures['time_to_recovery_ms']
        print(f'  {kind:<36} {figures["side"]:<6} {figures["count"]:>4} '
              f'{_milliseconds(safe["max"]) + " / " + _milliseconds(safe["p99"]):>21} '
              f'{_milliseconds(back["max"]) + " / " + _milliseconds(back["p99"]):>25}')
    for name, state in outcome['checks'].items():
        told = state if isinstance(state, str) else (
            f'{state["violations"]} violations on {", ".join(state["ran_on"])}')
        print(f'  {name}: {told}')
    if args.json:
        try:
            Path(args.json).write_text(json.dumps(outcome, indent=1) + '\n', encoding='utf-8')
        except OSError as error:
            print(f'kraft_master_report: cannot write {args.json}: {error}', file=sys.stderr)
            return 1
    print(f'{len(result.violations)} violations' if result.violations else 'all invariants hold')
    return 1 if result.violations else 0


def main(argv=None):
    """Write the report of a bag (or --check it); return 0, or 1 when unusable (or violated)."""
    args = _parser().parse_args(argv)
    if args.check:
        return check(args)
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
