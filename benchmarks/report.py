# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Time kraft_master_report on a synthetic session of a million samples, per storage plugin.

The session is simulated (the simulator's random-walk operator hand, read through the
nominal calibration with pot noise) and written as real CDR, each message serialised by
rosbags: joint_states, pose, pots and wrench per sample, diagnostics at 1 Hz; the bag of the
second storage is a copy of the first. Writing takes minutes; --bag-dir keeps the bags for
the next run. The report runs in this process as the command line runs it, twice: end to
end (the figure that counts, target 30 s), then phase by phase (read and decode, CSV,
figure, recalibration from the pots) to show where the time goes; last, rosbags' own
per-message reading and deserialisation of a sample of messages, extrapolated, for
comparison. Wall and CPU seconds are printed: on a shared machine wall time also counts
what other processes take.
"""
import argparse
from pathlib import Path
import shutil
import tempfile
import time

from kraft_master_driver.bag.common import typestore
from kraft_master_driver.bag.recorder import BagRecorder, STORAGES
from kraft_master_driver.bag.samples import simulate_samples, write_samples
from kraft_master_driver.core.calibration import ArmCalibration
from kraft_master_driver.tools import report, report_data, report_plots, report_tables
from rosbags.rosbag2 import Reader

TARGET_S = 30.0
BATCH = 100_000  # samples simulated and written at a time
START_NS = 1_767_225_600_000_000_000


class Stopwatch:
    """Wall and CPU time of a block."""

    def __enter__(self):
        """Start timing."""
        self.wall, self.cpu = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *_exc):
        """Stop timing."""
        self.wall = time.perf_counter() - self.wall
        self.cpu = time.process_time() - self.cpu

    def __str__(self):
        """Show both times."""
        return f'{self.wall:6.2f} s wall {self.cpu:6.2f} s CPU'


def synthesise(path, storage, samples):
    """Write a bag of `samples` simulated samples of the right arm at the root namespace."""
    start_ns = START_NS
    with BagRecorder(path, storage) as recorder:
        for start in range(0, samples, BATCH):
            count = min(BATCH, samples - start)
            batch = simulate_samples(count, seed=start, start_ns=start_ns)
            write_samples(recorder, '', batch)
            start_ns = int(batch.stamp[-1]) + 1_000_000
            print(f'  {start + count} samples written', end='\r', flush=True)
    print()


def convert(source, path, storage):
    """Copy every message of the bag `source` into a new bag with another storage plugin."""
    with Reader(source) as reader, BagRecorder(path, storage) as recorder:
        for connection in reader.connections:
            recorder.add_topic(connection.topic, connection.msgtype,
                               connection.ext.offered_qos_profiles)
        for connection, log_time, data in reader.messages():
            recorder.write(connection.topic, log_time, data)


def perturbed_calibration(directory):
    """Write a calibration whose lines differ from nominal by a few counts; return its path."""
    nominal = ArmCalibration.nominal('right')
    shifted = ArmCalibration('right', nominal.pot_a + 12.0, nominal.pot_b - 9.0,
                             nominal.angle_a, nominal.angle_b, source='perturbed')
    path = Path(directory) / 'perturbed.yaml'
    shifted.to_yaml(path)
    return path


def rosbags_baseline(bag, read_seconds, count=20_000):
    """Time rosbags' own Reader and deserialisation on `count` messages; print the ratio."""
    store = typestore()
    with Reader(bag) as reader:
        total = reader.message_count
        with Stopwatch() as reading:
            for index, (connection, _, data) in enumerate(reader.messages()):
                store.deserialize_cdr(data, connection.msgtype)
                if index + 1 == count:
                    break
    estimate = reading.cpu / count * total
    print(f'    rosbags Reader + deserialize_cdr: {reading.cpu / count * 1e6:.1f} us CPU per '
          f'message, about {estimate:.0f} s for all {total}: {estimate / read_seconds:.0f} '
          'times the read + decode above')


def phases(bag, out, calibration_path):
    """Run the report's phases one by one; print each one's time; return the read time."""
    calibration = ArmCalibration.from_yaml(calibration_path)
    with Stopwatch() as read:
        (arm_data,) = report_data.read_arms(bag)
    with Stopwatch() as recalibrating:
        recalibration = report_data.recalibrate(arm_data, calibration)
    with Stopwatch() as csv:
        report_tables.write_csv(Path(out) / 'phase_samples.csv', arm_data, recalibration)
    with Stopwatch() as figure:
        figure_path = Path(out) / 'phase.png'
        report_plots.draw(arm_data, recalibration, 'benchmark').savefig(figure_path, dpi=80)
    print(f'    read + decode  {read}  ({len(arm_data.stamp)} samples)')
    print(f'    recalibration  {recalibrating}')
    print(f'    CSV            {csv}')
    print(f'    figure         {figure}')
    return read.cpu


def main():
    """Synthesise the bags (unless kept), time the report on each; print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--samples', type=int, default=1_000_000)
    parser.add_argument('--storage', nargs='+', choices=sorted(STORAGES),
                        default=['mcap', 'sqlite3'])
    parser.add_argument('--bag-dir', help='keep the synthetic bags here and reuse them')
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix='kraft_report_bench_'))
    bag_dir = Path(args.bag_dir) if args.bag_dir else work
    bag_dir.mkdir(parents=True, exist_ok=True)
    calibration = perturbed_calibration(work)
    written = None  # a bag of the session already written: copied, not simulated again
    try:
        for storage in args.storage:
            bag = bag_dir / f'session_{args.samples}_{storage}'
            if not bag.exists():
                print(f'writing {bag} ...')
                with Stopwatch() as writing:
                    if written:
                        convert(written, bag, storage)
                    else:
                        synthesise(bag, storage, args.samples)
                print(f'  took {writing}')
            written = bag
            size = sum(f.stat().st_size for f in bag.iterdir()) / 1e6
            out = work / f'report_{storage}'
            with Stopwatch() as total:
                code = report.main([str(bag), '--out', str(out), '--calibration',
                                    str(calibration)])
            verdict = 'within' if total.wall < TARGET_S else 'OVER'
            print(f'{storage}: {args.samples} samples, {size:.0f} MB: report {total} '
                  f'(exit {code}), {verdict} the {TARGET_S:.0f} s target')
            rosbags_baseline(bag, phases(bag, out, calibration))
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == '__main__':
    main()
