# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_demo: the paper's worked examples, then a live readout of a simulated device.

The live part drives the built-in simulated hand controller over a real pseudo-terminal
through the same serial code the driver uses.
"""
import argparse
import math
import sys
import time

from kraft_master_driver import kinematics
from kraft_master_driver.calibration import ArmCalibration
from kraft_master_driver.device import KmcDevice
from kraft_master_driver.simulator import SimulatedKraftMaster
import numpy as np

SECTION_8_POTS = ((2086, 2683, 992, 1595, 1715, 2025), (2622, 1610, 2268, 1829, 2488, 1745))
ZERO_TORQUES = (0.0,) * kinematics.DRIVEN_JOINTS


def _rows(matrix, scales):
    return '\n'.join('    ' + ' '.join(f'{v * s:9.3f}' for v, s in zip(row, scales))
                     for row in matrix)


def print_examples(out=sys.stdout):
    """Print Section 8: pot counts -> joint angles -> 0T6 and 0J (mm in the printout)."""
    calibration = ArmCalibration.nominal('right')
    for number, pots in enumerate(SECTION_8_POTS, start=1):
        theta = calibration.pots_to_joints(pots)
        pose, jac = kinematics.forward_and_jacobian(theta)
        print(f'Section 8, example {number} (right arm): POT = {pots}', file=out)
        print('  th (deg) = ' + ', '.join(f'{math.degrees(t):.2f}' for t in theta), file=out)
        print('  0T6 (position in mm):', file=out)
        print(_rows(pose[:3], (1, 1, 1, 1000)), file=out)
        print('  0J (rows v in mm/rad, then w in rad/rad):', file=out)
        print(_rows(jac[:3], (1000,) * 6), file=out)
        print(_rows(jac[3:], (1,) * 6), file=out)
        print(file=out)


def live_readout(duration, rate_hz=1000.0, out=sys.stdout):
    """Cycle the simulated device for `duration` s, refreshing a short readout."""
    calibration = ArmCalibration.nominal('right')
    with SimulatedKraftMaster(arm='right', operator='sweep') as simulator:
        port = simulator.start()
        print(f'Simulated Kraft Master on {port}; reading it for {duration:g} s', file=out)
        with KmcDevice(port) as device:
            period = 1.0 / rate_hz
            start = next_print = time.monotonic()
            deadline, cycles = start, 0
            while time.monotonic() - start < duration:
                result = device.cycle(ZERO_TORQUES)
                cycles += result is not None
                now = time.monotonic()
                if result is not None and now >= next_print:
                    theta = calibration.pots_to_joints(result.frame.pots)
                    position = kinematics.forward(theta)[:3, 3] * 1000.0
                    angles = ' '.join(f'{v:7.2f}' for v in np.degrees(theta))
                    wrist = ' '.join(f'{v:7.1f}' for v in position)
                    print(f'\r{cycles / max(now - start, 1e-9):7.1f} cycles/s | th (deg) '
                          f'{angles} | wrist (mm) {wrist} | timeouts '
                          f'{device.stats.get("timeouts", 0)}', end='', file=out, flush=True)
                    next_print = now + 0.1
                deadline += period
                time.sleep(max(0.0, deadline - time.monotonic()))
        print(file=out)


def main(argv=None):
    """Print the examples and run the live readout."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--duration', type=float, default=10.0,
                        help='seconds of live readout (default 10)')
    args = parser.parse_args(argv)
    print_examples()
    try:
        live_readout(args.duration)
    except KeyboardInterrupt:
        print()
    return 0


if __name__ == '__main__':
    sys.exit(main())
