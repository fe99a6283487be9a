#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Plot felt force and master position over a push on the Panda, in simulated time (doc/figures/).

Runs test/harness/teleop_loop.py (test/ on the path) at 1000 N/m, the hand aiming 25 mm past the
table, at 0, 100 and 500 ms round trip, passivity off, on booking the contact force and on
booking the force sent (harness SENT_BOOKS), and draws over time how far the
master is past the table and the force the operator feels against the table's force. Every
value plotted is one of the runs'; the runs step simulated time, so they repeat digit for digit.
"""
import argparse
import pathlib
import sys

from harness.teleop_loop import run, SENT_BOOKS, Session
import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402, I100

ROUND_TRIPS = (0.0, 100.0, 500.0)  # ms
MODES = {'passivity off (plain J^T F)': ({}, '#c0392b'),
         'passivity on, books the contact force': ({'passivity': True}, '#7f8c8d'),
         'passivity on, books the force sent': (SENT_BOOKS, '#1f4e79')}


def draw(runs, title, output):
    """
    Draw the runs and write the figure to `output`.

    runs: {round trip (ms): [(label, colour, log of teleop_loop)]}, a column each; the top row
    how far the master is past the table, the bottom one the force felt and the table's.
    """
    figure, axes = plt.subplots(2, len(runs), figsize=(13, 6.5), sharex=True, sharey='row')
    for column, (round_trip, sessions) in enumerate(runs.items()):
        for label, colour, log in sessions:
            time = log[:, 0]
            axes[0, column].plot(time, 1e3 * log[:, 1], color=colour, lw=1, label=label)
            axes[1, column].plot(time, log[:, 5], color=colour, lw=1, label=f'felt, {label}')
            axes[1, column].plot(time, log[:, 4], color=colour, lw=0.8, ls=':',
                                 label=f"table's force, {label}")
        axes[0, column].set_title(f'{round_trip:.0f} ms round trip')
        axes[1, column].set_xlabel('time (s)')
    axes[0, 0].set_ylabel('master past the table (mm)')
    axes[1, 0].set_ylabel('force (N)')
    axes[0, 0].legend(fontsize=8)
    axes[1, 0].legend(fontsize=7)
    for axis in axes.flat:
        axis.grid(alpha=0.3)
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(output, dpi=90)


def main(argv=None):
    """Run the nine sessions and write the figure."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('output', type=pathlib.Path)
    args = parser.parse_args(argv)
    runs = {round_trip: [(label, colour, run(Session(round_trip_ms=round_trip, **settings))[0])
                         for label, (settings, colour) in MODES.items()]
            for round_trip in ROUND_TRIPS}
    draw(runs, 'The Panda at 1000 N/m, the hand aiming 25 mm past the table', args.output)
    return 0


if __name__ == '__main__':
    sys.exit(main())
