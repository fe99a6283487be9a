# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The Zenoh link's plain logic: streams, keys, and the session's configuration or refusal."""
from harness.certificates import openssl_missing, Sites
from kraft_master_driver.nodes import zenoh_config
import pytest


def test_the_streams_cross_once_each_way_and_nothing_else():
    assert zenoh_config.outgoing('master') == ('pose', 'master_energy', 'clutch')
    assert zenoh_config.outgoing('arm') == ('wrench', 'slave_energy', 'contact_model')
    assert zenoh_config.incoming('arm') == zenoh_config.outgoing('master')
    assert zenoh_config.incoming('master') == zenoh_config.outgoing('arm')


def test_each_key_names_the_pair_the_receiving_side_and_the_topic():
    assert zenoh_config.key('lab1/panda', 'pose', 'arm') == 'lab1/panda/to_arm/pose'
    assert zenoh_config.key('kraft_master/pair', 'wrench', 'master') == (
        'kraft_master/pair/to_master/wrench')


@pytest.mark.parametrize('pair', ['', 'lab1/', '/lab1', 'lab1//arm', 'lab/*', 'lab/**',
                                  'lab$x', 'lab?', 'lab#1', 'lab 1', None])
def test_a_pair_with_a_wildcard_or_an_empty_chunk_is_refused_in_one_line(pair):
    with pytest.raises(ValueError, match=r'^pair: .* must be chunks') as error:
        zenoh_config.check_pair(pair)
    assert '\n' not in str(error.value)


def test_a_side_other_than_master_or_arm_is_refused():
    with pytest.raises(ValueError, match=r"^side: 'slave' is not one of master, arm$"):
        zenoh_config.other_side('slave')


@pytest.mark.parametrize('endpoint', ['tls/10.0.0.2:7447', 'tls/[::1]:7447',
                                      'tls/arm.example.org:443'])
def test_tls_endpoints_are_taken(endpoint):
    assert zenoh_config.check_endpoint(endpoint, 'connect') == endpoint


@pytest.mark.parametrize('endpoint', ['tcp/10.0.0.2:7447', 'udp/10.0.0.2:7447', '10.0.0.2:7447',
                                      'tls/10.0.0.2', 'tls/10.0.0.2:0', 'tls/10.0.0.2:70000',
                                      'tls/:7447', 'quic/10.0.0.2:7447'])
def test_an_endpoint_that_is_not_tls_is_refused_in_one_line(endpoint):
    with pytest.raises(ValueError, match=r'^listen: .* is not tls/<host>:<port>') as error:
        zenoh_config.check_endpoint(endpoint, 'listen')
    assert '\n' not in str(error.value)


def test_a_missing_or_non_pem_file_is_refused_naming_the_parameter(tmp_path):
    with pytest.raises(ValueError, match=r'^tls.root_ca: cannot read .*/absent.pem: No such'):
        zenoh_config.check_pem(str(tmp_path / 'absent.pem'), 'tls.root_ca', 'CERTIFICATE')
    with pytest.raises(ValueError, match=r'^tls.certificate: no file given$'):
        zenoh_config.check_pem('', 'tls.certificate', 'CERTIFICATE')
    text = tmp_path / 'notes.txt'
    text.write_text('not a certificate\n')
    with pytest.raises(ValueError, match=r'^tls.certificate: .*notes.txt holds no PEM CERT'):
        zenoh_config.check_pem(str(text), 'tls.certificate', 'CERTIFICATE')
    with pytest.raises(ValueError, match=r'^tls.private_key: cannot read .*: Is a directory'):
        zenoh_config.check_pem(str(tmp_path), 'tls.private_key', 'PRIVATE KEY')


@pytest.mark.parametrize('name', ['', ' arm', 'arm,lab', None])
def test_a_peer_common_name_that_names_no_certificate_is_refused(name):
    with pytest.raises(ValueError, match=r'^tls.peer_common_name: '):
        zenoh_config.check_common_name(name)


def test_access_control_lets_the_peer_put_what_this_side_receives_and_nothing_else():
    control = zenoh_config.access_control('arm', 'lab1/panda', 'master')
    assert control['default_permission'] == 'deny'
    rules = {(r['messages'][0], r['flows'][0]): r['key_exprs'] for r in control['rules']}
    assert rules == {('put', 'ingress'): ['lab1/panda/to_arm/*'],
                     ('declare_subscriber', 'ingress'): ['lab1/panda/to_master/*'],
                     ('put', 'egress'): ['lab1/panda/to_master/*'],
                     ('declare_subscriber', 'egress'): ['lab1/panda/to_arm/*']}
    assert control['subjects'] == [{'id': 'peer_site', 'cert_common_names': ['master']}]
    assert control['policies'][0]['subjects'] == ['peer_site']
    assert len(control['policies'][0]['rules']) == 4


def test_exactly_one_of_listen_and_connect_is_given():
    for listen, connect in (('', ''), ('tls/0.0.0.0:7447', 'tls/10.0.0.2:7447')):
        with pytest.raises(ValueError, match=r'^listen, connect: give exactly one'):
            zenoh_config.session_config('arm', 'p', listen, connect, 'ca', 'c', 'k', 'master')


@pytest.fixture(scope='module')
def sites():
    """Yield a root CA and signed certificates for master and arm (openssl: a process)."""
    if openssl_missing():
        pytest.skip(openssl_missing())
    with Sites({'master': 'DNS:master-site', 'arm': 'IP:10.0.0.2'}) as made:
        yield made


@pytest.mark.process
def test_the_listening_side_speaks_only_tls_with_mutual_authentication(sites):
    arm = sites['arm']
    config = zenoh_config.session_config('arm', 'lab1/panda', 'tls/0.0.0.0:7447', '', sites.ca,
                                         arm.certificate, arm.private_key, 'master')
    assert config['mode'] == 'peer'
    assert config['listen'] == {'endpoints': ['tls/0.0.0.0:7447']}
    assert config['connect'] == {'endpoints': []}
    assert config['scouting'] == {'multicast': {'enabled': False}, 'gossip': {'enabled': False}}
    link = config['transport']['link']
    assert link['protocols'] == ['tls']
    assert link['tls'] == {'root_ca_certificate': sites.ca, 'listen_certificate': arm.certificate,
                           'listen_private_key': arm.private_key, 'enable_mtls': True}
    assert config['access_control'] == zenoh_config.access_control('arm', 'lab1/panda', 'master')


@pytest.mark.process
def test_the_connecting_side_backs_off_between_attempts(sites):
    master = sites['master']
    config = zenoh_config.session_config('master', 'lab1/panda', '', 'tls/10.0.0.2:7447',
                                         sites.ca, master.certificate, master.private_key, 'arm')
    assert config['connect']['endpoints'] == ['tls/10.0.0.2:7447']
    assert config['connect']['retry'] == {'period_init_ms': 500, 'period_max_ms': 4000,
                                          'period_increase_factor': 2}
    assert config['listen'] == {'endpoints': []}
    tls = config['transport']['link']['tls']
    assert tls['connect_certificate'] == master.certificate
    assert tls['connect_private_key'] == master.private_key
    # A certificate where the key belongs is refused before anything is opened.
    with pytest.raises(ValueError, match=r'^tls.private_key: .*master.pem holds no PEM PRIV'):
        zenoh_config.session_config('master', 'p', '', 'tls/10.0.0.2:7447', sites.ca,
                                    master.certificate, master.certificate, 'arm')


def test_the_pose_gate_is_shut_until_opened_and_opens_for_the_next_pose():
    gate = zenoh_config.PoseGate(0.05)
    assert gate.reason(10.0) == 'the link started'
    assert not gate.admit(10.0)
    gate.reopen()
    # However long the wait for the first pose after the bridge was disabled, it goes on.
    assert gate.reason(99.0) is None
    assert gate.admit(100.0) and gate.admit(100.05)


def test_a_gap_longer_than_the_timeout_shuts_the_gate_and_drops_the_pose_that_ends_it():
    gate = zenoh_config.PoseGate(0.05)
    gate.reopen()
    assert gate.admit(1.0)
    assert not gate.admit(1.051)
    assert gate.reason(1.06) == 'no pose for more than stream_timeout 0.05 s'
    assert not gate.admit(1.061)
    gate.reopen()
    assert gate.admit(1.07)


def test_a_lapsed_stream_shuts_the_gate_before_its_next_pose():
    gate = zenoh_config.PoseGate(0.05)
    gate.reopen()
    assert gate.admit(1.0)
    assert gate.reason(1.04) is None
    assert gate.reason(1.06) == 'no pose for more than stream_timeout 0.05 s'
    assert not gate.admit(1.07)


def test_the_peer_book_names_each_peer_and_counts_only_the_expected_one():
    book = zenoh_config.PeerBook('arm')
    assert book.update([('a1', 'tls/10.0.0.2:4001', 'arm'), ('a1', 'tls/10.0.0.2:4002', 'arm')]) \
        == [(False, 'authenticated peer arm connected (tls/10.0.0.2:4001)')]
    assert book.authenticated == 1
    assert book.update([('a1', 'tls/10.0.0.2:4001', 'arm')]) == []
    assert book.update([('a1', 'tls/10.0.0.2:4001', 'arm'),
                        ('o1', 'tls/10.0.0.9:5000', 'other-site')]) == [
        (True, 'peer tls/10.0.0.9:5000 shut out: it shows a certificate for other-site, not for '
               'arm (tls.peer_common_name); access control lets it put and subscribe nothing')]
    assert book.authenticated == 1
    assert book.update([]) == [(False, 'authenticated peer arm (tls/10.0.0.2:4001) gone'),
                               (False, 'shut-out peer other-site (tls/10.0.0.9:5000) gone')]
    assert book.authenticated == 0


def test_a_peer_without_a_certificate_name_is_shut_out():
    book = zenoh_config.PeerBook('master')
    ((warning, line),) = book.update([('x', 'tls/10.0.0.1:7447', None)])
    assert warning and line.startswith('peer tls/10.0.0.1:7447 shut out: it shows no '
                                       'certificate name, not for master')
    assert book.authenticated == 0
