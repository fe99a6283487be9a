# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""report_tables: the report's CSV numbers, formatted in bulk."""
import math

from kraft_master_driver.tools import report_tables
import numpy as np
import pytest


def test_csv_numbers_read_back_as_written():
    rng = np.random.default_rng(9)
    values = np.concatenate([rng.normal(0.0, 10.0, 1000), rng.normal(0.0, 1e-7, 100),
                             [0.0, -0.0, 1.0, -1.0, 0.5, -4e-10, 123456.0, math.nan, math.inf]])
    integers = rng.integers(-2**62, 2**62, len(values))
    lines = report_tables.csv_lines(
        [(values, 9), (integers, 0), (values, 3)]).decode().splitlines()
    assert len(lines) == len(values)
    for line, value, integer in zip(lines, values.tolist(), integers.tolist()):
        first, second, third = line.split(',')
        assert int(second) == integer
        if math.isfinite(value):
            assert float(first) == pytest.approx(value, abs=0.5e-9, rel=1e-15)
            assert float(third) == pytest.approx(value, abs=0.5e-3, rel=1e-15)
        else:
            assert first == third == ''
    assert [line.split(',')[0] for line in lines[-9:]] == [
        '0', '0', '1', '-1', '0.5', '0', '123456', '', '']
    # Too large for exact fixed point: written as Python writes floats.
    assert report_tables.csv_lines([(np.array([1e300, 2.5, math.nan]), 9)]) == b'1e+300\n2.5\n\n'
