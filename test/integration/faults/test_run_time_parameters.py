# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Bad parameter changes through the parameter service of the running driver."""
import statistics
import time

from harness.faults import bad_values, FaultSession, record, SETTLE_S
from kraft_master_driver.nodes.driver_parameters import PARAMETERS
import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rclpy.parameter import Parameter

pytestmark = [pytest.mark.faults, pytest.mark.integration]


def run_time_cases():
    """Parameter changes the running driver must refuse."""
    cases = []
    for name, spec in PARAMETERS.items():
        if spec.read_only:
            cases.append(pytest.param(name, 'read-only', spec.default, id=f'{name} read-only'))
            continue
        cases += [pytest.param(name, kind, value, id=f'{name} {kind}')
                  for kind, value in bad_values(name, spec)]
    return cases


@pytest.fixture(scope='class')
def parameter_session(install_prefix):
    """Run a driver session for the run-time parameter rows."""
    session = FaultSession(install_prefix)
    yield session
    session.close()


def parameter_message(name, value):
    """Return a Parameter message of `value`, typed as rclpy infers; None gives an unset one."""
    if value is None:
        return ParameterMsg(name=name)
    return Parameter(name, value=value).to_parameter_msg()


def torque_on(session, since_ns, count=20):
    """
    Wait for `count` steady torque commands in a row from `since_ns` on; return their median.

    Steady: each axis within the tolerance the tests compare with. On a loaded machine a
    wrench may go stale for a moment, and the force then ramps back in over force_ramp_time.
    """
    def on():
        commands = [c.counts for _, c in session.commands(since_ns)]
        for end in range(count, len(commands) + 1):
            window = commands[end - count:end]
            if all(any(c) for c in window) and all(
                    max(axis) - min(axis) <= steady_tolerance(statistics.median(axis))
                    for axis in zip(*window)):
                return window
        return None
    return [statistics.median(axis) for axis in zip(*session.wait(on))]


def steady_tolerance(counts):
    """Return how far (counts) a torque may move and still be the same: 5, or 5 %."""
    return max(5.0, 0.05 * abs(counts))


class TestRunTimeParameters:
    """Bad parameter changes through the parameter service of the running driver."""

    @pytest.mark.parametrize('name, kind, value', run_time_cases())
    def test_refused_and_torque_unchanged(self, parameter_session, name, kind, value):
        session = parameter_session
        client = session.parameter_client()
        torque = torque_on(session, time.time_ns())
        (current,) = session.call(client.get_parameters([name])).values
        result = session.call(client.set_parameters([parameter_message(name, value)])).results[0]
        assert not result.successful, f'{name} {kind} accepted'
        assert result.reason
        (unchanged,) = session.call(client.get_parameters([name])).values
        assert unchanged == current
        later = torque_on(session, time.time_ns())
        session.assert_alive()
        # The held arm settles a little under its torque; a refused change must not move it.
        assert all(abs(a - b) <= steady_tolerance(a) for a, b in zip(torque, later)), (
            torque, later)
        record('run time', f'{name} {kind}', outcome=result.reason)

    def test_a_valid_change_is_applied(self, parameter_session):
        """The control: force_scale 0.5 halves the torque, and 1.0 restores it."""
        session = parameter_session
        client = session.parameter_client()
        torque = torque_on(session, time.time_ns())
        for scale in (0.5, 1.0):
            result = session.call(client.set_parameters(
                [parameter_message('force_scale', scale)])).results[0]
            assert result.successful, result.reason
            session.client.spin(SETTLE_S)
            later = torque_on(session, time.time_ns())
            assert all(abs(scale * a - b) <= steady_tolerance(a)
                       for a, b in zip(torque, later)), (torque, later)

    def test_nothing_lost_across_the_parameter_changes(self, parameter_session):
        parameter_session.assert_alive()
        assert parameter_session.assert_nothing_lost() > 0
