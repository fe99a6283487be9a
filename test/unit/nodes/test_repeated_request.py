# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""RepeatedRequest against a real service that takes a request and never answers it."""
from harness.driver import next_domain_id, wait_for
from kraft_master_driver.nodes.ros_io import RepeatedRequest
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from std_srvs.srv import SetBool

PATIENCE_S = 1.0


class SteppedClock:
    """A clock the test moves: the waits for an answer do not depend on the machine's load."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


@pytest.fixture
def ros():
    """Yield a client spun by the test, and a server whose requests the test takes by hand."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=next_domain_id())
    client_node = rclpy.create_node('repeated_request_client', context=context)
    server_node = rclpy.create_node('repeated_request_server', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(client_node)
    client = client_node.create_client(SetBool, 'enable')
    # Never in an executor: what it takes, it answers only when the test says.
    service = server_node.create_service(SetBool, 'enable', lambda request, response: response)
    yield client, service, lambda: executor.spin_once(timeout_sec=0.01)
    executor.shutdown()
    client_node.destroy_node()
    server_node.destroy_node()
    rclpy.shutdown(context=context)


def take_request(service, spin):
    """Return (request, header) of the next request the service gets."""
    with service.handle:
        return wait_for(lambda: service.handle.service_take_request(SetBool.Request), spin=spin)


def answer(service, header, message):
    service.send_response(SetBool.Response(success=True, message=message), header)


def test_a_request_taken_and_never_answered_is_asked_again_and_only_the_new_answer_counts(ros):
    client, service, spin = ros
    clock = SteppedClock()
    request = RepeatedRequest(client, PATIENCE_S, clock=clock)
    answers = []
    assert not request.waiting() and not request.overdue()
    wait_for(client.service_is_ready, spin=spin)
    assert request.ask(SetBool.Request(data=False), answers.append)
    _, first = take_request(service, spin)
    # Not answered, not asked again before its patience is spent.
    clock.now = PATIENCE_S - 0.01
    assert request.waiting() and not request.overdue()
    assert not request.ask(SetBool.Request(data=False), answers.append)
    clock.now = PATIENCE_S
    assert request.overdue() and not request.waiting()
    assert request.ask(SetBool.Request(data=False), answers.append)
    _, second = take_request(service, spin)
    # The given-up request's late answer is ignored; the new one's is the answer.
    answer(service, first, 'late')
    answer(service, second, 'second')
    wait_for(lambda: answers, spin=spin)
    for _ in range(20):
        spin()
    assert [done.result().message for done in answers] == ['second']
    assert not request.waiting() and not request.overdue()


def test_nothing_is_sent_while_no_server_is_matched():
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=next_domain_id())
    try:
        node = rclpy.create_node('repeated_request_alone', context=context)
        request = RepeatedRequest(node.create_client(SetBool, 'enable'), PATIENCE_S)
        assert not request.ask(SetBool.Request(data=False), lambda done: None)
        assert not request.waiting() and not request.overdue()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
