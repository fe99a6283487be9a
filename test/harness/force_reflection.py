# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The force reflection under test: an enabled one, its inputs, and what zero torque is."""
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.force_reflection import ForceReflection
import pytest

T0 = 5_000_000_000_000  # an arbitrary time.monotonic_ns() reading
NO_LIMIT = (1e9,) * 5
ZERO5, ZERO6 = (0.0,) * 5, (0.0,) * 6
WRENCH = (3.0, -2.0, 5.0, 0.3, 0.2, -0.4)


def reflection(**kwargs):
    """Return an enabled ForceReflection, without saturation unless torque_limits is given."""
    kwargs.setdefault('torque_limits', NO_LIMIT)
    return ForceReflection(enabled=True, **kwargs)


def pose_and_jacobian(theta):
    """Return (0T6, 0R6, 0J) at theta."""
    pose, jac = kinematics.forward_and_jacobian(theta)
    return pose, pose[:3, :3], jac


def assert_zero(out, state):
    """Assert exactly zero torques with the given state."""
    assert out.actuator == ZERO5
    assert out.joint == ZERO6
    assert out.state == state
    assert out.saturated is False
    assert out.tag is None


def assert_bad_setting_changes_nothing(make, name, value, valid_change):
    """Assert that make(**{name: value}) and configure() raise naming it, and change nothing."""
    with pytest.raises(ValueError, match=name):
        make(**{name: value})
    subject = make()
    before = subject.settings
    with pytest.raises(ValueError, match=name):
        subject.configure(**{name: value})
    with pytest.raises(ValueError, match=name):
        subject.configure(**valid_change, **{name: value})
    assert subject.settings == before
