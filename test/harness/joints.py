# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Joint vectors for the tests of what the wrist pose drives: force reflection, rate control."""
from kraft_master_driver.core import kinematics


def random_theta(rng):
    """Return a joint vector inside the Table II limits (elbow bound coupled to th2)."""
    lower, upper = kinematics.joint_limits()
    theta = rng.uniform(lower, upper)
    lower, upper = kinematics.joint_limits(theta[1])
    theta[2] = rng.uniform(lower[2], upper[2])
    return theta
