# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The SROS2 policy: well formed (sros2's policy format 0.2.0) and naming the nodes' endpoints."""
import xml.etree.ElementTree as ElementTree

from harness import REPO
from harness.driver import DriverProcess, next_domain_id, wait_for
import pytest
import rclpy

POLICY = REPO / 'security' / 'kraft_master_teleop.policy.xml'
DRIVER, SLAVE = '/kraft_master/driver', '/kraft_master/slave'
NAMESPACES = {'/', '/right', '/left'}
RULES = {'topics': ('topic', {'publish', 'subscribe'}),
         'services': ('service', {'reply', 'request'}),
         'actions': ('action', {'call', 'execute'})}


def load():
    """Return the policy's root element."""
    return ElementTree.parse(POLICY).getroot()


def resolve(name, namespace, node):
    """Fully qualified name of `name` as a node `node` in `namespace` would resolve it."""
    if name.startswith('~/'):
        name = f'{node}/{name[2:]}'
    elif name.startswith('/'):
        return name
    return namespace.rstrip('/') + '/' + name


def grants(profile):
    """Return {(rule, qualifier): {fully qualified names}} that `profile` allows."""
    allowed = {}
    for group in profile:
        child, _ = RULES[group.tag]
        for rule, qualifier in group.attrib.items():
            allowed.setdefault((rule, qualifier), set()).update(
                resolve(e.text, profile.get('ns'), profile.get('node'))
                for e in group.findall(child))
    return allowed


def enclave_profiles(path):
    """Return the profiles of the enclave at `path`."""
    return load().findall(f'enclaves/enclave[@path="{path}"]/profiles/profile')


def test_policy_has_the_structure_of_sros2_policy_format_0_2_0():
    root = load()
    assert root.tag == 'policy' and root.attrib == {'version': '0.2.0'}
    assert [child.tag for child in root] == ['enclaves']
    enclaves = list(root[0])
    assert [e.tag for e in enclaves] == ['enclave'] * 2
    assert {e.get('path') for e in enclaves} == {DRIVER, SLAVE}
    for enclave in enclaves:
        assert set(enclave.attrib) == {'path'}
        assert [child.tag for child in enclave] == ['profiles']
        profiles = list(enclave[0])
        assert profiles and {p.tag for p in profiles} == {'profile'}
        for profile in profiles:
            assert set(profile.attrib) == {'ns', 'node'}
            for group in profile:
                child, qualifiers = RULES[group.tag]
                assert group.attrib and set(group.attrib) <= qualifiers
                assert set(group.attrib.values()) <= {'ALLOW', 'DENY'}
                assert len(group) >= 1 and {e.tag for e in group} == {child}
                assert all(e.text and e.text.strip() == e.text and not len(e) for e in group)


def test_every_namespace_of_the_package_has_the_same_profile_per_node():
    for path, nodes in ((DRIVER, {'kraft_master_node'}),
                        (SLAVE, {'kraft_master_teleop', 'kraft_master_slave_sim'})):
        profiles = enclave_profiles(path)
        assert {p.get('node') for p in profiles} == nodes
        for node in nodes:
            of_node = [p for p in profiles if p.get('node') == node]
            assert sorted(p.get('ns') for p in of_node) == sorted(NAMESPACES)
            contents = {tuple((g.tag, tuple(g.attrib.items()), tuple(e.text for e in g))
                              for g in p) for p in of_node}
            assert len(contents) == 1


def test_only_the_slave_enclave_may_publish_wrench():
    publishers = {enclave.get('path')
                  for enclave in load().findall('enclaves/enclave')
                  for profile in enclave.findall('profiles/profile')
                  if any(name.endswith('/wrench') for name in
                         grants(profile).get(('publish', 'ALLOW'), ()))}
    assert publishers == {SLAVE}


def endpoints(node, name, namespace):
    """Return the grants a policy must give node `name` in `namespace`, from the ROS graph."""
    if (name, namespace) not in node.get_node_names_and_namespaces():
        return {}
    found = {
        ('publish', 'ALLOW'): node.get_publisher_names_and_types_by_node(name, namespace),
        ('subscribe', 'ALLOW'): node.get_subscriber_names_and_types_by_node(name, namespace),
        ('reply', 'ALLOW'): node.get_service_names_and_types_by_node(name, namespace),
        ('request', 'ALLOW'): node.get_client_names_and_types_by_node(name, namespace),
    }
    return {key: {topic for topic, _ in value} for key, value in found.items() if value}


def merged(*grant_sets):
    """Union of several {(rule, qualifier): names} dicts."""
    union = {}
    for grant_set in grant_sets:
        for key, names in grant_set.items():
            union.setdefault(key, set()).update(names)
    return union


@pytest.fixture
def running_nodes(install_prefix):
    """Start installed nodes in namespace /right, each alone in a domain; yield the graph."""
    started = []

    def start(executable, node_name, parameters):
        domain_id = next_domain_id()
        process = DriverProcess(install_prefix, domain_id, parameters, namespace='/right',
                                name=executable)
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain_id)
        lister = rclpy.create_node('policy_lister', context=context)
        started.append((process, lister, context))
        return lambda: endpoints(lister, node_name, '/right')

    yield start
    for process, lister, context in started:
        lister.destroy_node()
        rclpy.try_shutdown(context=context)
        process.kill()


def test_policy_names_exactly_the_endpoints_of_the_running_nodes(running_nodes):
    expected = {node: grants(next(p for p in enclave_profiles(path)
                                  if p.get('ns') == '/right' and p.get('node') == node))
                for path, node in ((DRIVER, 'kraft_master_node'), (SLAVE, 'kraft_master_teleop'),
                                   (SLAVE, 'kraft_master_slave_sim'))}
    # rate_command is advertised once rate_command_enabled is true (at start or at run time),
    # contact_model taken with force_mode other than direct: the policy allows both, so the
    # driver runs with them on.
    driver = running_nodes('kraft_master_node', 'kraft_master_node',
                           [('port', 'sim'), ('rate_command_enabled', 'true'),
                            ('force_mode', 'auto')])
    # The bridge's and the arm's endpoints depend on their mode (and the bridge's joy on its
    # clutch_button): the policy allows both modes.
    bridge_modes = [running_nodes('kraft_master_teleop', 'kraft_master_teleop', parameters)
                    for parameters in ([('mode', 'pose')],
                                       [('mode', 'twist'), ('clutch_button', '0')])]
    arm_modes = [running_nodes('kraft_master_slave_sim', 'kraft_master_slave_sim',
                               [('mode', mode)]) for mode in ('pose', 'twist')]

    def bridge():
        return merged(*(mode() for mode in bridge_modes))

    def arm():
        return merged(*(mode() for mode in arm_modes))

    for node, graph in (('kraft_master_node', driver), ('kraft_master_teleop', bridge),
                        ('kraft_master_slave_sim', arm)):
        try:
            wait_for(lambda: graph() == expected[node], timeout=60.0)
        except AssertionError:
            pass
        assert graph() == expected[node]
