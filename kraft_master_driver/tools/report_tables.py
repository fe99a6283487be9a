# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The text of kraft_master_report: the per-sample CSV of an arm, and the summary it prints.

The CSV is formatted by numpy, CSV_CHUNK rows at a time, not number by number, and reads back
as written (test/unit/tools/test_report_tables.py).
"""
import os
from typing import Sequence

from kraft_master_driver.core import kinematics
from kraft_master_driver.tools.report_data import (
    ArmData, diagnostics_series, last_values, link_errors, LOOP_COUNTERS, loop_periods,
    Recalibration)
import numpy as np
from numpy.typing import ArrayLike

CSV_CHUNK = 65536  # rows formatted at once

# Text is built one character position at a time: rows of N characters, which numpy fills
# fast, NUL where a character is left out. Digits come from uint32 chunks of nine digits
# (integer division by a constant is fast for 32-bit integers).
_CHUNK = 10 ** 9
_ZERO = ord('0')


def _decimal_text(scaled, decimals, negative, present):
    """
    Render non-negative int64 `scaled` (in units of 10**-decimals) as a (width, N) array.

    Leading zeros of the integer part and trailing zeros of the fraction are left out, and
    so is the whole field where `present` is False.
    """
    chunks = []  # [digits above this chunk are non-zero (N,) bool, the chunk's value (N,)]
    while len(chunks) * 9 <= decimals or chunks[-1][0].any():
        scaled, chunk = np.divmod(scaled, _CHUNK)
        chunks.append([scaled != 0, chunk.astype(np.uint32)])
    fraction_seen = np.zeros(len(present), bool)
    fraction_rows, integer_rows = [], []
    for place in range(9 * len(chunks)):
        higher, value = chunks[place // 9]
        remaining = value != 0  # before this digit is taken
        if place > decimals and not (remaining.any() or higher.any()):
            break
        quotient = value // 10
        digit = (value - quotient * 10).astype(np.uint8) + _ZERO
        chunks[place // 9][1] = quotient
        if place < decimals:
            fraction_seen |= digit != _ZERO
            fraction_rows.append(digit * fraction_seen)
        else:
            integer_rows.append(digit * (remaining | higher | (place == decimals)))
    rows = [np.where(negative, ord('-'), 0).astype(np.uint8)] + integer_rows[::-1]
    if decimals:
        rows += [(fraction_seen * ord('.')).astype(np.uint8)] + fraction_rows[::-1]
    return np.stack(rows) * present.astype(np.uint8)


def number_text(values: ArrayLike, decimals: int) -> np.ndarray:
    """
    Render float or integer values as decimal text with at most `decimals` decimals.

    Returns a (width, N) uint8 array, NUL for characters left out; NaN and infinite values
    give empty fields. Values too large for exact fixed point are written by repr.
    """
    values = np.asarray(values)
    if values.dtype.kind in 'iu':
        return _decimal_text(np.abs(values.astype(np.int64)), 0, values < 0,
                             np.ones(len(values), bool))
    present = np.isfinite(values)
    finite = np.where(present, values, 0.0)
    largest = float(np.abs(finite).max(initial=0.0))
    if largest * 10 ** decimals >= 2 ** 53:
        text = np.array([repr(v) if ok else '' for v, ok in zip(finite.tolist(), present)],
                        dtype=bytes)
        return text.view(np.uint8).reshape(len(values), -1).T
    scaled = np.rint(np.abs(finite) * 10 ** decimals).astype(np.int64)
    return _decimal_text(scaled, decimals, (finite < 0) & (scaled > 0), present)


def csv_lines(columns: Sequence[tuple[np.ndarray, int]]) -> bytes:
    """Return the CSV bytes of equal-length columns, each (values, decimals)."""
    pieces = []
    for values, decimals in columns:
        pieces += [number_text(values, decimals),
                   np.full((1, len(values)), ord(','), np.uint8)]
    pieces[-1] = np.full((1, len(values)), ord('\n'), np.uint8)
    width = sum(len(piece) for piece in pieces)
    characters = np.zeros((-(-width // 8), 8, len(values)), np.uint8)
    np.concatenate(pieces, out=characters.reshape(-1, len(values))[:width])
    # Into row order eight character positions at a time (faster than one transpose),
    # then drop the NULs in one pass.
    lines = np.empty((len(values), len(characters), 8), np.uint8)
    for position in range(8):
        lines[:, :, position] = characters[:, position, :].T
    return lines.tobytes().translate(None, b'\0')


def csv_columns(arm_data: ArmData, recalibration: Recalibration | None = None
                ) -> tuple[list[str], list[tuple[np.ndarray, int]]]:
    """Return (header names, [(values, decimals)]) of the per-sample CSV."""
    names = list(kinematics.JOINT_NAMES)
    header, columns = ['stamp_ns'], [(arm_data.stamp, 0)]
    blocks = [('position', arm_data.position, 9), ('velocity', arm_data.velocity, 6),
              ('effort', arm_data.effort, 6)]
    for quantity, values, decimals in blocks:
        header += [f'{name}_{quantity}' for name in names]
        columns += [(values[:, i], decimals) for i in range(6)]
    header += [f'pot{i}' for i in range(1, 7)] + ['x', 'y', 'z', 'qx', 'qy', 'qz', 'qw']
    columns += [(arm_data.pots[:, i], 3) for i in range(6)]
    columns += [(arm_data.wrist[:, i], 9) for i in range(3)]
    columns += [(arm_data.orientation[:, i], 9) for i in range(4)]
    if recalibration is not None:
        header += [f'recal_{name}_position' for name in names]
        header += ['recal_x', 'recal_y', 'recal_z', 'recal_qx', 'recal_qy', 'recal_qz',
                   'recal_qw']
        columns += [(recalibration.position[:, i], 9) for i in range(6)]
        columns += [(recalibration.wrist[:, i], 9) for i in range(3)]
        columns += [(recalibration.orientation[:, i], 9) for i in range(4)]
    return header, columns


def write_csv(path: str | os.PathLike, arm_data: ArmData,
              recalibration: Recalibration | None = None) -> None:
    """Write the per-sample CSV of one arm."""
    header, columns = csv_columns(arm_data, recalibration)
    with open(path, 'wb') as stream:
        stream.write((','.join(header) + '\n').encode())
        for start in range(0, len(arm_data.stamp), CSV_CHUNK):
            part = slice(start, start + CSV_CHUNK)
            stream.write(csv_lines([(values[part], decimals) for values, decimals in columns]))


def summary(arm_data: ArmData, recalibration: Recalibration | None = None) -> list[str]:
    """Return text lines describing one arm's session."""
    label = arm_data.namespace or '/'
    count = len(arm_data.stamp)
    span = (arm_data.stamp[-1] - arm_data.stamp[0]) / 1e9 if count > 1 else 0.0
    lines = [f'{label} ({arm_data.arm} arm): {count} samples over {span:.3f} s']
    periods = loop_periods(arm_data.stamp)
    if len(periods):
        median, p99 = np.percentile(periods, (50, 99)) * 1e3
        lines.append(f'  loop period median {median:.3f} ms, p99 {p99:.3f} ms, '
                     f'max {periods.max() * 1e3:.3f} ms')
    if arm_data.diagnostics:
        _, counters = link_errors(arm_data.diagnostics)
        loop = last_values(diagnostics_series(arm_data.diagnostics, LOOP_COUNTERS)[1])
        errors = ', '.join(f'{name} {values[-1]:.0f}' for name, values in counters.items())
        lines.append(f'  {len(arm_data.diagnostics)} diagnostics messages: '
                     + ''.join(f'{key} {value:.0f}, ' for key, value in loop.items())
                     + f'link errors: {errors or "none"}')
    if arm_data.missing:
        lines.append(f'  missing topics: {", ".join(arm_data.missing)}')
    lines += [f'  {note}' for note in arm_data.notes]
    if recalibration is not None:
        change = np.degrees(np.abs(recalibration.position - arm_data.position))
        worst = np.max(np.nan_to_num(change, nan=-np.inf), axis=0, initial=-np.inf)
        moved = np.max(np.nan_to_num(np.linalg.norm(recalibration.wrist - arm_data.wrist,
                                                    axis=1), nan=-np.inf), initial=-np.inf)
        joints = ', '.join(f'{name} {value:.3f}' for name, value
                           in zip(kinematics.JOINT_NAMES, worst) if np.isfinite(value))
        lines.append(f'  recalibrated with {recalibration.source}: largest joint angle change '
                     f'(deg) {joints or "none (no pots and joint_states)"}')
        if np.isfinite(moved):
            lines.append(f'  largest wrist position change {moved * 1e3:.3f} mm')
    return lines
