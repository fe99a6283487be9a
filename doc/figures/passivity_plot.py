#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Plot one run of benchmarks/delay_model.py, passivity off against on (doc/figures/).

Reads the JSON the benchmark writes with --json (doc/figures/delay_model.json is the run
doc/design/passivity-experiments.md shows) and draws, against the round trip, the master's
peak-to-peak over the hold, the energy the channel generated and the force the operator felt;
the rows without loss as lines, those with 1 and 10 % loss as points. Every value plotted is
one of the file's.
"""
import argparse
import json
import pathlib
import sys

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402, I100

HERE = pathlib.Path(__file__).resolve().parent
COLOURS = {'off': '#c0392b', 'on': '#1f4e79'}
LABELS = {'off': 'passivity off (plain J^T F)', 'on': 'passivity on'}
PANELS = (('master_pp_mm', "master's peak-to-peak over the hold (mm)", 'linear'),
          ('energy_generated_j', 'energy the channel generated (J)', 'symlog'),
          ('force_felt_n', 'force the operator felt (N)', 'linear'))
MARKERS = {1.0: 's', 10.0: '^'}


def plot(rows, path, caption):
    """Draw the three panels of `rows` into `path`, with `caption` under them."""
    trips = sorted({row['round_trip_ms'] for row in rows})
    position = {trip: i for i, trip in enumerate(trips)}
    fig, axes = plt.subplots(1, 3, figsize=(14.0, 4.6))
    for ax, (key, title, scale) in zip(axes, PANELS):
        for mode in ('off', 'on'):
            lossless = sorted((row['round_trip_ms'], row[key]) for row in rows
                              if row['passivity'] == mode and row['loss_pct'] == 0.0)
            ax.plot([position[t] for t, _ in lossless], [v for _, v in lossless], '-o',
                    color=COLOURS[mode], label=LABELS[mode] + ', no loss')
            for loss, marker in MARKERS.items():
                lossy = [(row['round_trip_ms'], row[key]) for row in rows
                         if row['passivity'] == mode and row['loss_pct'] == loss]
                ax.plot([position[t] for t, _ in lossy], [v for _, v in lossy], marker,
                        color=COLOURS[mode], markerfacecolor='none', markersize=8,
                        label=f'{LABELS[mode]}, {loss:g} % loss')
        if scale == 'symlog':
            ax.set_yscale('symlog', linthresh=1e-3)
            ax.axhline(0.0, color='#888888', linewidth=0.8)
        ax.set_xticks(range(len(trips)), [f'{t:g}' for t in trips])
        ax.set_xlabel('round trip (ms)')
        ax.set_title(title, fontsize=11)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8, loc='upper left')
    fig.text(0.5, 0.01, caption, ha='center', fontsize=9, color='#444444')
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None):
    """Plot the JSON given into the PNG given."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('json', nargs='?', type=pathlib.Path,
                        default=HERE / 'delay_model.json')
    parser.add_argument('out', nargs='?', type=pathlib.Path, default=HERE / 'delay_model.png')
    args = parser.parse_args(argv)
    rows = json.loads(args.json.read_text())['rows']
    plot(rows, args.out, 'benchmarks/delay_model.py --json doc/figures/delay_model.json: '
         "the driver's and the slave's classes stepped together in simulated time "
         '(device 1 kHz, slave 500 Hz, exact delay)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
