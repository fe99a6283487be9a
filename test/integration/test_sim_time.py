# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""What ROS users see of the nodes: /diagnostics under use_sim_time, the bridge's wrench QoS."""
from diagnostic_msgs.msg import DiagnosticArray
from harness.driver import DriverProcess, next_domain_id, RosClient
import pytest
from rclpy.qos import ReliabilityPolicy

pytestmark = pytest.mark.integration


@pytest.mark.parametrize('name', ['kraft_master_node', 'kraft_master_slave_sim',
                                  'kraft_master_teleop'])
def test_diagnostics_go_on_under_sim_time_without_a_clock(install_prefix, name):
    domain_id = next_domain_id()
    parameters = [('use_sim_time', 'true')]
    if name == 'kraft_master_node':
        parameters.append(('port', 'sim'))
    node = DriverProcess(install_prefix, domain_id, parameters, name=name)
    client = RosClient(domain_id)
    try:
        arrays = []
        client.node.create_subscription(DiagnosticArray, '/diagnostics', arrays.append, 10)
        client.wait(lambda: len(arrays) >= 3)
        # Stamped with the node's clock: ROS time, 0 until a /clock comes.
        assert arrays[-1].header.stamp.sec == 0
    finally:
        client.close()
        node.kill()


def test_the_bridge_publishes_wrench_reliable(install_prefix):
    domain_id = next_domain_id()
    slave = DriverProcess(install_prefix, domain_id, name='kraft_master_teleop')
    client = RosClient(domain_id)
    try:
        (info,) = client.wait(lambda: client.node.get_publishers_info_by_topic('/wrench'))
        assert info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    finally:
        client.close()
        slave.kill()
