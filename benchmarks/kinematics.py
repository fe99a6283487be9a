# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Time the closed-form kinematics against a plain chain of numpy DH products, in one run.

Prints the median microseconds per call of forward_and_jacobian and of forward (one joint
vector, both results), the same for a product of the six 4x4 DH matrices with an np.cross
Jacobian, their ratios, and the batch throughput of forward_and_jacobian in poses per second.
Targets: the closed form at least 20 times faster than the chain, batches above 2 M poses/s.
"""
import argparse
import os
import platform
import statistics
import time

from kraft_master_driver.core import kinematics
import numpy as np

SPEEDUP_TARGET = 20.0
BATCH_TARGET = 2e6
BATCH_SIZES = (100_000, 1_000_000)


def chain_forward(theta, arm='right'):
    """Return 0T6 and the frames {1}..{6} from the product of the six DH link transforms."""
    frames = []
    transform = np.eye(4)
    for alpha, a, d, angle in kinematics.dh_table(theta, arm):
        transform = transform @ kinematics.dh_transform(alpha, a, d, angle)
        frames.append(transform)
    return transform, frames


def chain_forward_and_jacobian(theta, arm='right'):
    """Return 0T6 and 0J; column i is (z_i x (p_6 - p_i), z_i) for the revolute joint i."""
    transform, frames = chain_forward(theta, arm)
    wrist = transform[:3, 3]
    jacobian = np.empty((6, 6))
    for column, frame in enumerate(frames):
        axis = frame[:3, 2]
        jacobian[:3, column] = np.cross(axis, wrist - frame[:3, 3])
        jacobian[3:, column] = axis
    return transform, jacobian


def per_call_us(function, argument, blocks, calls_per_block):
    """Return the per-call times (us) of `blocks` timed blocks of back-to-back calls."""
    times = []
    for _ in range(blocks):
        start = time.perf_counter()
        for _ in range(calls_per_block):
            function(argument)
        times.append((time.perf_counter() - start) / calls_per_block * 1e6)
    return times


def interleaved(candidates, argument, rounds, blocks, calls_per_block):
    """Time each candidate in turn, round after round, so that noise hits all alike."""
    times = {name: [] for name in candidates}
    for _ in range(rounds):
        for name, function in candidates.items():
            times[name] += per_call_us(function, argument, blocks, calls_per_block)
    return times


def describe(times):
    """Return 'median [p10, p90]' of a list of times."""
    deciles = statistics.quantiles(times, n=10)
    return f'{statistics.median(times):8.2f} [{deciles[0]:.2f}, {deciles[-1]:.2f}]'


def verdict(met):
    """Return the word for a target met or missed."""
    return 'met' if met else 'NOT MET'


def check_chain_agrees(rng):
    """Return the largest difference between the chain and the closed form."""
    worst = 0.0
    for theta in rng.uniform(-np.pi, np.pi, (200, 6)):
        for got, want in zip(chain_forward_and_jacobian(theta),
                             kinematics.forward_and_jacobian(theta)):
            worst = max(worst, float(np.abs(got - want).max()))
    return worst


def batch_rates(size, repeats, rng):
    """Return forward_and_jacobian poses per wall second and per CPU second, per run."""
    thetas = rng.uniform(-np.pi, np.pi, (size, 6))
    kinematics.forward_and_jacobian(thetas)  # warm-up: the first touch of fresh memory is slow
    wall, cpu = [], []
    for _ in range(repeats):
        wall_start, cpu_start = time.perf_counter(), time.process_time()
        kinematics.forward_and_jacobian(thetas)
        wall.append(size / (time.perf_counter() - wall_start))
        cpu.append(size / (time.process_time() - cpu_start))
    return wall, cpu


def main(argv=None):
    """Run the benchmark and print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--rounds', type=int, default=5, help='interleaved rounds')
    parser.add_argument('--blocks', type=int, default=40, help='timed blocks per round')
    parser.add_argument('--batch-repeats', type=int, default=5, help='runs of each batch size')
    args = parser.parse_args(argv)
    rng = np.random.default_rng(2026)
    theta = np.radians([-25.0, 40.0, -100.0, -35.0, 10.0, 20.0])

    print(f'kinematics benchmark: Python {platform.python_version()}, numpy {np.__version__}, '
          f'{os.cpu_count()} CPUs, batch chunk {kinematics.BATCH_CHUNK}')
    print(f'chain agrees with the closed form to {check_chain_agrees(rng):.1e}')
    print(f'\none call, microseconds: median [p10, p90] over {args.rounds * args.blocks} '
          'timed blocks')
    pairs = (
        ('forward_and_jacobian', kinematics.forward_and_jacobian, chain_forward_and_jacobian,
         SPEEDUP_TARGET),
        ('forward', kinematics.forward, chain_forward, None),
    )
    for label, closed_form, chain, target in pairs:
        times = interleaved({'closed form': closed_form, 'numpy chain': chain}, theta,
                            args.rounds, args.blocks, calls_per_block=50)
        for name, values in times.items():
            print(f'  {label:<21} {name:<12} {describe(values)}')
        ratio = statistics.median(times['numpy chain']) / statistics.median(times['closed form'])
        goal = '' if target is None else f'   (target >= {target:g}x: {verdict(ratio >= target)})'
        print(f'  {label:<21} chain / closed form {ratio:6.1f}x{goal}')

    print('\nbatch forward_and_jacobian, million poses per second (per CPU second in brackets)')
    for size in BATCH_SIZES:
        wall, cpu = batch_rates(size, args.batch_repeats, rng)
        median, cpu_median = statistics.median(wall), statistics.median(cpu)
        print(f'  N = {size:>9,}: median {median / 1e6:5.2f} [{cpu_median / 1e6:.2f}], '
              f'best {max(wall) / 1e6:5.2f}, worst {min(wall) / 1e6:5.2f} over {len(wall)} runs'
              f'   (target > {BATCH_TARGET / 1e6:g}: {verdict(median > BATCH_TARGET)})')


if __name__ == '__main__':
    main()
