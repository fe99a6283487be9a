# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Potentiometer calibration of the Kraft Master (Section 6 of NASA TM-104124).

Pots are in the paper's order POT1..POT6. Each pot reads one angle along a straight
line through two points (POT_a, angle_a) and (POT_b, angle_b) (Eq. 11). POT3 reads the
absolute elbow link angle th2 + th3; POT4 reads wrist pitch th5 and POT5 wrist yaw th4
(Table III). Angles are radians in code and degrees in the YAML file, which is a
ROS 2 parameter file that the node takes unchanged with --params-file.
"""
from collections.abc import Iterable, Sequence
import math
import numbers
import os
from typing import Any, NamedTuple, Self

from kraft_master_driver.core.kinematics import ARMS
import numpy as np
from numpy.typing import ArrayLike, NDArray
import yaml

POT_COUNT = 6
POT_MAX = 4095
# Joint index (th1..th6) that each pot POT1..POT6 reads; POT3 reads th2 + th3.
POT_JOINT = (0, 1, 2, 4, 3, 5)
POT_MEASURES = ('th1', 'th2', 'th2 + th3', 'th5', 'th4', 'th6')
CALIBRATION_KEYS = ('pot_a', 'pot_b', 'angle_a_deg', 'angle_b_deg')

# Tables IV and V of the paper, pot order POT1..POT6.
_NOMINAL_POTS = {
    'right': ((157, 751, 248, 1126, 500, 1395), (4014, 3328, 3863, 2766, 2930, 2656)),
    'left': ((119, 777, 240, 1228, 808, 1402), (3983, 3354, 3859, 2856, 3280, 2634)),
}
_NOMINAL_ANGLES_DEG = ((90.0, 0.0, 35.0, -20.0, 55.0, 45.0),
                       (-90.0, 120.0, -135.0, 50.0, -55.0, -45.0))


class CalibrationError(ValueError):
    """A calibration that cannot be used; the message names the source, key and fault."""


class FitResult(NamedTuple):
    """A least-squares calibration and its residuals per pot (radians)."""

    calibration: 'ArmCalibration'
    rms_residual: NDArray[np.float64]
    max_residual: NDArray[np.float64]
    sample_count: NDArray[np.int64]


class ArmCalibration:
    """Two-point lines from pot counts to the angle each pot reads, for one arm."""

    def __init__(self, arm: str, pot_a: Iterable[float], pot_b: Iterable[float],
                 angle_a: Iterable[float], angle_b: Iterable[float],
                 source: str = 'calibration') -> None:
        """Build from per-pot arrays (pot order, counts and radians); validate all of it."""
        if arm not in ARMS:
            raise CalibrationError(
                f"{source}: arm: unknown arm {arm!r}, expected 'right' or 'left'")
        self.arm = arm
        self.source = source
        self.pot_a = _vector(pot_a, source, 'pot_a', 0.0, POT_MAX, 'counts')
        self.pot_b = _vector(pot_b, source, 'pot_b', 0.0, POT_MAX, 'counts')
        self.angle_a = _vector(angle_a, source, 'angle_a', -2 * math.pi, 2 * math.pi, 'rad')
        self.angle_b = _vector(angle_b, source, 'angle_b', -2 * math.pi, 2 * math.pi, 'rad')
        # Named by their parameter keys; angles are shown in the parameters' degrees.
        for key, first, second, shown in (('pot_b', self.pot_a, self.pot_b, float),
                                          ('angle_b_deg', self.angle_a, self.angle_b,
                                           math.degrees)):
            equal = np.flatnonzero(first == second)
            if equal.size:
                pot = equal[0]
                raise CalibrationError(
                    f'{source}: calibration.{key}: POT{pot + 1} has its two calibration '
                    f'points equal ({shown(first[pot]):g}); the line through them is undefined')
        self.slope = (self.angle_b - self.angle_a) / (self.pot_b - self.pot_a)
        self.offset = self.angle_a - self.slope * self.pot_a
        self._lines = tuple(zip(self.offset.tolist(), self.slope.tolist()))

    @classmethod
    def nominal(cls, arm: str) -> Self:
        """Return the paper's calibration of the right or left unit (Tables IV and V)."""
        if arm not in _NOMINAL_POTS:
            raise CalibrationError(
                f"nominal: arm: unknown arm {arm!r}, expected 'right' or 'left'")
        pot_a, pot_b = _NOMINAL_POTS[arm]
        angle_a, angle_b = (np.radians(a) for a in _NOMINAL_ANGLES_DEG)
        return cls(arm, pot_a, pot_b, angle_a, angle_b, source=f'nominal {arm} arm')

    def pots_to_joints(self, pots: ArrayLike) -> NDArray[np.float64]:
        """Return joint angles th1..th6 (rad) from pot counts POT1..POT6, (6,) or (N, 6)."""
        measured = self.offset + self.slope * np.asarray(pots, dtype=float)
        theta: NDArray[np.float64] = measured[..., POT_JOINT]
        theta[..., 2] -= theta[..., 1]
        return theta

    def frame_to_joints(self, pots: Iterable[float]) -> list[float]:
        """
        Return th1..th6 (rad) of one frame of six pot counts as a list of floats.

        pots_to_joints without numpy for the control loop; the same floats.
        """
        measured = [offset + slope * count for (offset, slope), count in zip(self._lines, pots)]
        theta = [measured[pot] for pot in POT_JOINT]
        theta[2] -= theta[1]
        return theta

    def joints_to_frame(self, theta: Sequence[float]) -> list[float]:
        """
        Return the pot counts (unrounded) that read th1..th6 (six floats) as a list of floats.

        joints_to_pots without numpy for the simulator's serving thread; the same floats.
        """
        measured = [theta[joint] for joint in POT_JOINT]
        measured[2] += theta[1]
        return [(value - offset) / slope for (offset, slope), value in zip(self._lines, measured)]

    def joints_to_pots(self, theta: ArrayLike) -> NDArray[np.float64]:
        """Return the pot counts (unrounded floats) that read joint angles th1..th6."""
        theta = np.asarray(theta, dtype=float)
        measured = theta[..., POT_JOINT]
        measured[..., 2] += theta[..., 1]
        return (measured - self.offset) / self.slope

    @classmethod
    def fit(cls, arm: str, samples: Sequence[tuple[ArrayLike, ArrayLike]],
            source: str = 'least-squares fit') -> FitResult:
        """
        Fit each pot's line by least squares from many (counts, known angle) samples.

        samples holds, for each pot POT1..POT6 in order, a pair (counts, angles): the
        counts read and the known angle (rad) of what that pot measures (POT3: th2 + th3).
        The fitted line is stored as two points at the smallest and largest count seen.
        """
        if len(samples) != POT_COUNT:
            raise CalibrationError(
                f'{source}: need samples for {POT_COUNT} pots, got {len(samples)}')
        pot_a, pot_b, angle_a, angle_b = (np.empty(POT_COUNT) for _ in range(4))
        rms, worst, count = np.empty(POT_COUNT), np.empty(POT_COUNT), np.empty(POT_COUNT, int)
        for i, (counts, angles) in enumerate(samples):
            counts = np.asarray(counts, dtype=float).ravel()
            angles = np.asarray(angles, dtype=float).ravel()
            if counts.shape != angles.shape or counts.size < 2 or counts.min() == counts.max():
                raise CalibrationError(
                    f'{source}: POT{i + 1}: need matching counts and angles at two or more '
                    f'distinct counts, got {counts.size} counts and {angles.size} angles')
            if not (np.all(np.isfinite(counts)) and np.all(np.isfinite(angles))):
                raise CalibrationError(f'{source}: POT{i + 1}: samples must be finite numbers')
            slope, offset = np.polyfit(counts, angles, 1)
            residual = angles - (offset + slope * counts)
            pot_a[i], pot_b[i] = counts.min(), counts.max()
            angle_a[i], angle_b[i] = offset + slope * pot_a[i], offset + slope * pot_b[i]
            rms[i] = math.sqrt(float(np.mean(residual ** 2)))
            worst[i] = float(np.max(np.abs(residual)))
            count[i] = counts.size
        return FitResult(cls(arm, pot_a, pot_b, angle_a, angle_b, source), rms, worst, count)

    def to_parameters(self) -> dict[str, str | dict[str, list[float]]]:
        """Return the calibration as ROS parameter values (degrees in the file)."""
        return {
            'arm': self.arm,
            'calibration': {
                'pot_a': [float(x) for x in self.pot_a],
                'pot_b': [float(x) for x in self.pot_b],
                'angle_a_deg': [round(math.degrees(x), 9) for x in self.angle_a],
                'angle_b_deg': [round(math.degrees(x), 9) for x in self.angle_b],
            },
        }

    @classmethod
    def from_parameters(cls, arm: str, calibration: object, source: str) -> Self:
        """Build from the `calibration` parameter mapping of a parameter file or the node."""
        if not isinstance(calibration, dict):
            raise CalibrationError(f'{source}: calibration: expected a mapping with keys '
                                   f'{", ".join(CALIBRATION_KEYS)}')
        missing = [key for key in CALIBRATION_KEYS if key not in calibration]
        if missing:
            raise CalibrationError(f'{source}: calibration.{missing[0]}: missing key')
        angles = []
        for key in ('angle_a_deg', 'angle_b_deg'):
            values = _vector(calibration[key], source, key, -360.0, 360.0, 'deg')
            angles.append(np.radians(values))
        angle_a, angle_b = angles
        return cls(arm, calibration['pot_a'], calibration['pot_b'], angle_a, angle_b,
                   source=source)

    @classmethod
    def from_yaml(cls, path: str | os.PathLike[str]) -> Self:
        """Load from a ROS 2 parameter file such as config/right_arm.yaml."""
        params = read_parameter_file(path)
        if 'arm' not in params:
            raise CalibrationError(f'{path}: arm: missing key')
        if 'calibration' not in params:
            raise CalibrationError(f'{path}: calibration: missing key')
        return cls.from_parameters(params['arm'], params['calibration'], str(path))

    def to_yaml(self, path: str | os.PathLike[str], node_name: str = '/**',
                header: str = '') -> None:
        """Write a ROS 2 parameter file that from_yaml and the node read back unchanged."""
        text = yaml.safe_dump({node_name: {'ros__parameters': self.to_parameters()}},
                              default_flow_style=None, sort_keys=False)
        comment = ''.join(f'# {line}\n' for line in header.splitlines())
        with open(path, 'w', encoding='utf-8') as stream:
            stream.write(comment + text)

    def __repr__(self) -> str:
        """Show the arm and the source of the calibration."""
        return f'ArmCalibration(arm={self.arm!r}, source={self.source!r})'


def yaml_fault(path: str | os.PathLike[str], error: Exception) -> str:
    """Return one line naming the file, the line and the fault of a YAML error (PyYAML: four)."""
    mark = getattr(error, 'problem_mark', None)
    where = f'{path} line {mark.line + 1}' if mark else path
    problem = getattr(error, 'problem', None) or str(error)
    context = getattr(error, 'context', None)
    return f'{where}: not valid YAML: {problem}' + (f' ({context})' if context else '')


def read_parameter_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Return the ros__parameters mapping of a one-node ROS 2 parameter file."""
    try:
        with open(path, encoding='utf-8') as stream:
            document = yaml.safe_load(stream)
    except OSError as error:
        raise CalibrationError(f'{path}: cannot read: {error.strerror}') from error
    except UnicodeDecodeError as error:
        raise CalibrationError(f'{path}: not UTF-8 text: {error}') from error
    except yaml.YAMLError as error:
        raise CalibrationError(yaml_fault(path, error)) from None
    if not isinstance(document, dict) or len(document) != 1:
        raise CalibrationError(
            f'{path}: expected one node section such as "/**:" holding "ros__parameters:"')
    (section,) = document.values()
    if not isinstance(section, dict) or not isinstance(section.get('ros__parameters'), dict):
        raise CalibrationError(f'{path}: ros__parameters: missing or not a mapping')
    parameters: dict[str, Any] = section['ros__parameters']
    return parameters


def _vector(values: object, source: str, key: str, low: float, high: float,
            unit: str) -> NDArray[np.float64]:
    where = f'{source}: calibration.{key}'
    items = values.tolist() if isinstance(values, np.ndarray) else values
    if isinstance(items, (str, bytes, dict)) or not hasattr(items, '__iter__'):
        raise CalibrationError(f'{where}: expected a list of {POT_COUNT} numbers, got {values!r}')
    items = list(items)
    if len(items) != POT_COUNT:
        raise CalibrationError(f'{where}: expected {POT_COUNT} numbers, got {len(items)}')
    for pot, item in enumerate(items, 1):
        if isinstance(item, bool) or not isinstance(item, numbers.Real):
            raise CalibrationError(f'{where}: POT{pot} is {item!r}, expected a number')
    array = np.array(items, dtype=float)
    bad = np.flatnonzero(~np.isfinite(array) | (array < low) | (array > high))
    if bad.size:
        raise CalibrationError(f'{where}: POT{bad[0] + 1} is {array[bad[0]]:g}, expected a '
                               f'finite value within {low:g}..{high:g} {unit}')
    return array
