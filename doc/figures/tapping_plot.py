#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Plot five touches of the table, direct force against the contact model (doc/figures/).

Runs benchmarks/tapping.py's sessions (test/harness/teleop_loop.py, test/ on the path): the
table at 1000 N/m behind the Panda's 1000 N/m, the master read through whole pot counts, 1 %
loss and 5 ms of jitter, at 0, 250 and 1000 ms round trip, force_mode direct and model; and
draws over time how far the master is past the table and the force the operator feels against
the table's force. Every value plotted is one of the runs'; simulated time, digit for digit.
"""
import argparse
import pathlib
import sys

from harness.teleop_loop import Session, tap, Tapping
from teleop_quality_plot import draw  # beside this script

ROUND_TRIPS = (0.0, 250.0, 1000.0)  # ms
MODES = {'direct (J^T F)': ('direct', '#c0392b'), 'contact model': ('model', '#1f4e79')}


def main(argv=None):
    """Run the six sessions and write the figure."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('output', type=pathlib.Path)
    args = parser.parse_args(argv)
    runs = {round_trip: [(label, colour, tap(Session(
        round_trip, 0.01, jitter_ms=5.0, pot_counts=True, force_mode=mode,
        table_stiffness=1000.0), Tapping())[0]) for label, (mode, colour) in MODES.items()]
        for round_trip in ROUND_TRIPS}
    draw(runs, 'Five touches, each aiming 15 mm past the table (1000 N/m)', args.output)
    return 0


if __name__ == '__main__':
    sys.exit(main())
