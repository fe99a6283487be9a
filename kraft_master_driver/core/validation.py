# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Checks of settings, no ROS: each returns the value, or raises ValueError naming it."""
from collections.abc import Callable, Iterable, Mapping, Sequence
import math
import numbers
from typing import Any

import numpy as np


def interval_text(lower: float, upper: float, lower_open: bool) -> str:
    """Return the interval as text: [0, 5], (0, inf)."""
    return f'{"(" if lower_open else "["}{lower:g}, {upper:g}{")" if upper == math.inf else "]"}'


def finite_real(name: str, value: object, lower: float = 0.0, upper: float = math.inf,
                lower_open: bool = False) -> float:
    """Return value as a float if it is a finite real number in range, else raise ValueError."""
    if type(value) is not float:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise ValueError(f'{name} must be a number, got {value!r}')
        value = float(value)
    if not (math.isfinite(value) and lower <= value <= upper
            and not (lower_open and value == lower)):
        raise ValueError(
            f'{name} must be finite and in {interval_text(lower, upper, lower_open)}, got {value}')
    return value


def finite_reals(name: str, values: Iterable[object], length: int,
                 lower_open: bool = False) -> tuple[float, ...]:
    """Return a tuple of `length` finite non-negative floats (positive if lower_open)."""
    if isinstance(values, (str, bytes)):
        raise ValueError(f'{name} must be {length} numbers, got {values!r}')
    try:
        values = list(values)
    except TypeError:
        raise ValueError(f'{name} must be {length} numbers, got {values!r}') from None
    if len(values) != length:
        raise ValueError(f'{name} must be {length} numbers, got {len(values)}')
    return tuple(finite_real(f'{name}[{i}]', v, lower_open=lower_open)
                 for i, v in enumerate(values))


def flag(name: str, value: object) -> bool:
    """Return value as a bool if it is one (numpy's too), else raise ValueError."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f'{name} must be True or False, got {value!r}')
    return bool(value)


def choice(name: str, choices: Sequence[str], value: str) -> str:
    """Return value if it is one of `choices`, else raise ValueError."""
    if value not in choices:
        raise ValueError(f'{name} must be one of {", ".join(choices)}, got {value!r}')
    return value


def checked_changes(changes: Mapping[str, object],
                    validators: Mapping[str, Callable[[Any], object]]) -> dict[str, Any]:
    """Return each change as its validator returns it; raise ValueError on an unknown name."""
    unknown = sorted(set(changes) - set(validators))
    if unknown:
        raise ValueError(
            f'unknown setting(s) {", ".join(unknown)}; known: {", ".join(validators)}')
    return {name: validators[name](value) for name, value in changes.items()}
