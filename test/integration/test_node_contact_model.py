# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The installed driver with force_mode model (and auto): contact_model rendered as a wall."""
import math

from harness.driver import DriverSession
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.contact_model import MODEL_FIELDS
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

pytestmark = pytest.mark.integration

DEPTH = 0.005  # m: the hand this far inside the wall
STIFFNESS = 500.0  # N/m: under the renderable wall's clip (740 N/m at 1 kHz)
UP = (0.0, 0.0, 1.0)
# The simulated hand yields (about 290 N/m along UP at home): the wall's force peaks near 1.35 N
# as it ramps in, then settles near 0.9 N. Pressed is judged against the settled force.
PRESSED_N = 0.25 * STIFFNESS * DEPTH


@pytest.fixture
def session(install_prefix):
    """Yield a driver that renders contact_model, force on, and a model publisher."""
    running = model_session(install_prefix, [('force_mode', 'model')])
    yield running
    running.close()


def model_session(install_prefix, parameters):
    """Start a driver with `parameters`, force on, and a model publisher beside its client."""
    # A model_timeout longer than any wait here: only the refusal takes the wall away.
    running = DriverSession(install_prefix, [*parameters, ('model_timeout', '10'),
                                             ('force_enabled_at_start', 'true')])
    running.model_pub = running.client.node.create_publisher(
        JointState, 'contact_model', QoSProfile(depth=10,
                                                reliability=ReliabilityPolicy.BEST_EFFORT))
    running.client.wait(lambda: running.model_pub.get_subscription_count() > 0 and
                        running.client.poses)
    return running


def publish_model(session, names, values):
    message = JointState(name=list(names), position=[float(v) for v in values])
    message.header.stamp = session.client.node.get_clock().now().to_msg()
    session.model_pub.publish(message)


def wall_over_the_hand(session):
    """Return a model whose plane is DEPTH above the hand, its normal up."""
    position = session.client.poses[-1].pose.position
    point = (position.x, position.y, position.z + DEPTH)
    return [*point, *UP, STIFFNESS, 0.0, 1.0, 1.0]


def stream_model_until(session, names, values, condition):
    """Publish the model every few ms until `condition()` holds."""
    def publish_and_check():
        publish_model(session, names, values)
        return condition()
    return session.client.wait(publish_and_check)


def felt_force(state):
    """Return the force along UP whose J^T best explains the effort, and the fit's residual."""
    column = kinematics.jacobian(state.position).T @ np.array([*UP, 0.0, 0.0, 0.0])
    column[5] = 0.0
    effort = np.array(state.effort)
    force = float(column @ effort / (column @ column))
    return force, float(np.abs(effort - force * column).max())


def pressed(session):
    state = session.client.joint_states[-1]
    return any(state.effort) and felt_force(state)[0] > PRESSED_N


def released(session):
    return not any(session.client.joint_states[-1].effort) and not any(
        session.last_command())


def test_a_wall_over_the_hand_pushes_it_down_along_its_normal(session):
    # The plane's normal points up and the hand is under it: the wall pushes the hand along
    # the normal, at most its spring force (the simulated hand yields a little).
    stream_model_until(session, MODEL_FIELDS, wall_over_the_hand(session),
                       lambda: pressed(session))
    force, residual = felt_force(session.client.joint_states[-1])
    assert PRESSED_N < force <= STIFFNESS * DEPTH * 1.01
    assert residual < 1e-3


def with_value(values, index, value):
    values = list(values)
    values[index] = value
    return values


@pytest.mark.parametrize('bad', ['not finite', 'negative stiffness', 'normal not unit',
                                 'fields misnamed', 'a value missing'])
def test_a_bad_model_takes_the_wall_away_and_a_good_one_brings_it_back(session, bad):
    good = wall_over_the_hand(session)
    stream_model_until(session, MODEL_FIELDS, good, lambda: pressed(session))
    names, values = {
        'not finite': (MODEL_FIELDS, with_value(good, 6, math.nan)),
        'negative stiffness': (MODEL_FIELDS, with_value(good, 6, -STIFFNESS)),
        'normal not unit': (MODEL_FIELDS, with_value(good, 5, 2.0)),
        'fields misnamed': (('x', *MODEL_FIELDS[1:]), good),
        'a value missing': (MODEL_FIELDS, good[:-1]),
    }[bad]
    stream_model_until(session, names, values, lambda: released(session))
    stream_model_until(session, MODEL_FIELDS, good, lambda: pressed(session))
    _, output = session.driver.interrupt()
    assert 'contact_model: ' in output and ': no wall' in output, output[-2000:]


def test_with_passivity_on_auto_renders_the_wall_at_0_ms_and_direct_force_once_it_is_off(
        install_prefix):
    # A zero wrench and the model, both stamped now (0 ms): auto with passivity on renders the
    # wall; turned off at run time, auto gives the direct (zero) wrench again.
    running = model_session(install_prefix, [('force_mode', 'auto'), ('passivity', 'true')])
    try:
        model = wall_over_the_hand(running)

        def stream_both_until(condition):
            def publish_and_check():
                running.client.publish_wrench([0.0] * 6, 'kraft_master_base')
                publish_model(running, MODEL_FIELDS, model)
                return condition()
            return running.client.wait(publish_and_check)

        stream_both_until(lambda: pressed(running))
        parameters = AsyncParameterClient(running.client.node, '/kraft_master_node')
        assert parameters.wait_for_services(timeout_sec=20.0)
        future = parameters.set_parameters([Parameter('passivity', value=False)])
        running.client.wait(future.done)
        assert future.result().results[0].successful
        stream_both_until(lambda: not any(running.client.joint_states[-1].effort))
    finally:
        running.close()
