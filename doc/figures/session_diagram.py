#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Draw the processes and topics of a teleoperation session (doc/figures/session.png).

The boxes are the package's console scripts as `make demo` runs them (the simulated device,
the driver, the bridge, the simulated arm) with the link emulator that `make demo DELAY_MS=...`
puts between the two DDS domains, and the recorder and report of a session. The names on the
arrows are those the nodes create (kraft_master_driver/nodes/). Matplotlib only, so that any
machine with `make venv` redraws it: `make doc-figures`.
"""
import argparse
import pathlib
import sys

import matplotlib

matplotlib.use('Agg')
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch, Rectangle  # noqa: E402, I100
import matplotlib.pyplot as plt  # noqa: E402

MASTER_SIDE = '#eef3fb'
SLAVE_SIDE = '#fbf1e8'
PROCESS = '#ffffff'
EDGE = '#34495e'
TOPIC = '#1f4e79'
SERIAL = '#7b3f00'


def box(ax, x, y, width, height, title, note, dashed=False):
    """Draw a process box centred at (x, y) with a bold title and a note under it."""
    ax.add_patch(FancyBboxPatch(
        (x - width / 2, y - height / 2), width, height,
        boxstyle='round,pad=0.01,rounding_size=0.015',
        facecolor=PROCESS, edgecolor=EDGE, linewidth=1.6, linestyle='--' if dashed else '-'))
    ax.text(x, y + (0.022 if note else 0.0), title, ha='center', va='center', fontsize=11,
            fontweight='bold', family='monospace')
    ax.text(x, y - 0.03, note, ha='center', va='center', fontsize=8.5, color='#444444')


def arrow(ax, start, end, label, colour=TOPIC, offset=(0.0, 0.018), both=False, rad=0.0):
    """Draw an arrow from start to end with a label beside its middle."""
    ax.add_patch(FancyArrowPatch(
        start, end, arrowstyle='<|-|>' if both else '-|>', mutation_scale=14, linewidth=1.5,
        color=colour, connectionstyle=f'arc3,rad={rad}'))
    middle = ((start[0] + end[0]) / 2 + offset[0], (start[1] + end[1]) / 2 + offset[1])
    ax.text(*middle, label, ha='center', va='center', fontsize=8.5, color=colour,
            family='monospace', linespacing=1.3)


def draw(path):
    """Draw the diagram into `path`."""
    fig = plt.figure(figsize=(13.0, 6.2))
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.axis('off')

    ax.add_patch(Rectangle((0.01, 0.02), 0.63, 0.9, facecolor=MASTER_SIDE, edgecolor='none'))
    ax.add_patch(Rectangle((0.64, 0.02), 0.35, 0.9, facecolor=SLAVE_SIDE, edgecolor='none'))
    ax.text(0.02, 0.895, "operator's side: DDS domain N", fontsize=10, color=EDGE,
            va='top', style='italic')
    ax.text(0.98, 0.895, "arm's side: domain N + 1 behind the emulator\n"
            '(make demo DELAY_MS=...), domain N without it', fontsize=10, color=EDGE,
            va='top', ha='right', style='italic')
    ax.text(0.5, 0.965, 'A teleoperation session: processes (boxes) and the topics between them',
            ha='center', va='center', fontsize=13, fontweight='bold')

    row = 0.6
    box(ax, 0.1, row, 0.17, 0.13, 'kraft_master_sim',
        'simulated KMC 9100 and\nhand (or the device)')
    box(ax, 0.41, row, 0.19, 0.13, 'kraft_master_node',
        'the driver: 1 kHz loop,\nJ^T F to torques')
    box(ax, 0.64, row, 0.17, 0.13, 'kraft_master_\nlink_emulator',
        '\ndelay, jitter, loss\n(optional)', dashed=True)
    box(ax, 0.87, row, 0.19, 0.13, 'kraft_master_\nteleop',
        '\nthe bridge: clutch,\nmapping, slave port')

    arrow(ax, (0.185, row), (0.315, row), 'serial link\n(pty or TCP)', colour=SERIAL,
          offset=(0.0, 0.045), both=True)
    ax.text(0.25, row - 0.07, 'command, 15 B:\ntorques \u2192\nreply, 18 B:\n\u2190 pots',
            ha='center', va='center', fontsize=8.5, color=SERIAL, family='monospace')
    for start, end in (((0.505, row + 0.035), (0.555, row + 0.035)),
                       ((0.725, row + 0.035), (0.775, row + 0.035)),
                       ((0.775, row - 0.035), (0.725, row - 0.035)),
                       ((0.555, row - 0.035), (0.505, row - 0.035))):
        arrow(ax, start, end, '')
    ax.text(0.64, row + 0.11, 'pose, master_energy  \u2192', ha='center', fontsize=9.5,
            color=TOPIC, family='monospace')
    ax.text(0.64, row - 0.11, '\u2190  wrench, slave_energy', ha='center', fontsize=9.5,
            color=TOPIC, family='monospace')

    box(ax, 0.41, 0.81, 0.19, 0.06, 'kraft_master_ctl', '')
    arrow(ax, (0.41, 0.78), (0.41, row + 0.065), 'services:\nenable_force,\nset_center',
          offset=(-0.1, 0.0))

    out = 0.31
    ax.text(0.41, out + 0.02, 'joint_states, pose, pots, master_energy,\n'
            'rate_command (optional), /diagnostics', ha='center', fontsize=9, color=TOPIC,
            family='monospace')
    arrow(ax, (0.41, row - 0.065), (0.41, out + 0.07), '')
    box(ax, 0.87, out, 0.19, 0.11, 'kraft_master_\nslave_sim',
        '\nsimulated arm, F/T,\nwall (or a real arm)')
    arrow(ax, (0.81, row - 0.065), (0.81, out + 0.055), 'servo_cp\n(servo_cv)',
          offset=(-0.045, 0.0))
    arrow(ax, (0.93, out + 0.055), (0.93, row - 0.065), 'measured_cp,\nmeasured_cf',
          offset=(-0.06, 0.0))

    box(ax, 0.2, 0.12, 0.2, 0.09, 'kraft_master_record', 'a rosbag2 bag (mcap or sqlite3)')
    box(ax, 0.47, 0.12, 0.2, 0.09, 'kraft_master_report', 'a PNG and a CSV per arm')
    arrow(ax, (0.36, out - 0.01), (0.24, 0.165), "the driver's topics\nand wrench",
          offset=(-0.08, 0.0))
    arrow(ax, (0.3, 0.12), (0.37, 0.12), 'bag', offset=(0.0, 0.02))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None):
    """Draw the diagram into the path given (default doc/figures/session.png)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('out', nargs='?', type=pathlib.Path,
                        default=pathlib.Path(__file__).with_name('session.png'))
    draw(parser.parse_args(argv).out)
    return 0


if __name__ == '__main__':
    sys.exit(main())
