# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Rate mode, no ROS: a velocity command from the wrist's offset to a centre (Section 4)."""
import math

from kraft_master_driver.core import kinematics
from kraft_master_driver.core.validation import finite_real
import numpy as np
from numpy.typing import ArrayLike, NDArray


def _outside_dead_band(vector: list[float], gain: float, dead_band: float) -> list[float]:
    """Return gain * vector with its length shrunk by dead_band (zero inside the band)."""
    length = math.hypot(*vector)
    if length <= dead_band:
        return [0.0, 0.0, 0.0]
    factor = gain * (1.0 - dead_band / length)
    return [factor * x for x in vector]


def rate_command(
        pose: ArrayLike, centre: ArrayLike, linear_gain: float, angular_gain: float,
        linear_dead_band: float = 0.0, angular_dead_band: float = 0.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """
    Return (v, w), each (3,) in {0}: a rate-mode velocity command from the wrist's offset.

    The Section 4 pose difference (kinematics.pose_difference(pose, centre)) times the gains
    (1/s). The dead bands (m, rad) are subtracted from the lengths of dp and of the rotation
    vector, so small offsets command nothing and the command stays continuous. A non-finite
    result gives zero velocities.
    """
    linear_gain = finite_real('linear_gain', linear_gain, lower=-math.inf)
    angular_gain = finite_real('angular_gain', angular_gain, lower=-math.inf)
    linear_dead_band = finite_real('linear_dead_band', linear_dead_band)
    angular_dead_band = finite_real('angular_dead_band', angular_dead_band)
    dp, dw = kinematics.pose_difference(pose, centre)
    v = _outside_dead_band(dp.tolist(), linear_gain, linear_dead_band)
    w = _outside_dead_band(dw.tolist(), angular_gain, angular_dead_band)
    if not all(map(math.isfinite, v + w)):
        return np.zeros(3), np.zeros(3)
    return np.array(v), np.array(w)
