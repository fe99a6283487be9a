# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""BagRecorder's bags read by independent readers, field by field against rosbag2 Jazzy's."""
import sqlite3

from harness.type_hashes import generated_type_hash
from kraft_master_driver.bag.common import (
    DIAGNOSTIC_ARRAY, JOINT_STATE, POSE_STAMPED, typestore, WRENCH_STAMPED)
from kraft_master_driver.bag.reader import read_topics
from kraft_master_driver.bag.recorder import (
    _share_directory, BagRecorder, message_definition, STORAGES)
from kraft_master_driver.bag.samples import simulate_samples, write_samples
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rosbags.rosbag2 import Reader
import yaml

STORE = typestore()
# The tables rosbag2 Jazzy creates (rosbag2_storage_sqlite3/src/.../sqlite_storage.cpp,
# branch jazzy, SqliteStorage::initialize), as sqlite_master keeps them.
JAZZY_SQLITE3_TABLES = [
    'CREATE TABLE schema(schema_version INTEGER PRIMARY KEY,ros_distro TEXT NOT NULL)',
    'CREATE TABLE metadata(id INTEGER PRIMARY KEY,metadata_version INTEGER NOT NULL,'
    'metadata TEXT NOT NULL)',
    'CREATE TABLE topics(id INTEGER PRIMARY KEY,name TEXT NOT NULL,type TEXT NOT NULL,'
    'serialization_format TEXT NOT NULL,offered_qos_profiles TEXT NOT NULL,'
    'type_description_hash TEXT NOT NULL)',
    'CREATE TABLE message_definitions(id INTEGER PRIMARY KEY,topic_type TEXT NOT NULL,'
    'encoding TEXT NOT NULL,encoded_message_definition TEXT NOT NULL,'
    'type_description_hash TEXT NOT NULL)',
    'CREATE TABLE messages(id INTEGER PRIMARY KEY,topic_id INTEGER NOT NULL,'
    'timestamp INTEGER NOT NULL, data BLOB NOT NULL)',
    'CREATE INDEX timestamp_idx ON messages (timestamp ASC)',
]
SAMPLES = 1000


def record(path, storage):
    """Write two arms' synthetic sessions; return the closed BagRecorder."""
    with BagRecorder(path, storage) as recorder:
        for namespace, seed in (('/left', 1), ('/right', 2)):
            samples = simulate_samples(SAMPLES, namespace[1:], seed=seed)
            write_samples(recorder, namespace, samples, diagnostics_every=500)
    return recorder


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    """Return {storage: (bag directory, its BagRecorder)}."""
    paths = {storage: tmp_path_factory.mktemp(storage) / 'session_a'
             for storage in STORAGES}
    return {storage: (path, record(path, storage)) for storage, path in paths.items()}


def metadata_yaml(path):
    """Return the map under rosbag2_bagfile_information of a bag's metadata.yaml."""
    return yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']


@pytest.mark.parametrize('storage', STORAGES)
def test_metadata_is_rosbag2_jazzy(bags, storage):
    path, recorder = bags[storage]
    info = metadata_yaml(path)
    file_name = f'session_a_0.{"mcap" if recorder.storage == "mcap" else "db3"}'
    assert sorted(p.name for p in path.iterdir()) == sorted([file_name, 'metadata.yaml'])
    assert info['version'] == 9 and info['ros_distro'] == 'jazzy'
    assert info['storage_identifier'] == recorder.storage
    assert info['relative_file_paths'] == [file_name]
    assert info['files'][0]['path'] == file_name
    assert info['message_count'] == sum(recorder.counts.values())
    assert info['message_count'] == 2 * (4 * SAMPLES + SAMPLES // 500)
    for entry in info['topics_with_message_count']:
        topic = entry['topic_metadata']
        assert entry['message_count'] == recorder.counts[topic['name']]
        assert topic['serialization_format'] == 'cdr'
        assert topic['type_description_hash'] == generated_type_hash(topic['type'])
        assert topic['offered_qos_profiles'][0]['reliability'] == 'reliable'
    with Reader(path) as reader:
        assert reader.message_count == info['message_count']
        assert {c.topic: c.msgcount for c in reader.connections} == recorder.counts


def test_mcap_read_by_the_mcap_package(bags):
    path, recorder = bags['mcap']
    info = metadata_yaml(path)
    with open(path / 'session_a_0.mcap', 'rb') as stream:
        # Every record, the chunk and summary CRCs checked.
        assert sum(1 for _ in StreamReader(stream, validate_crcs=True).records) > 10
    with open(path / 'session_a_0.mcap', 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        channels = {channel.topic: channel for channel in summary.channels.values()}
        assert {t: summary.statistics.channel_message_counts[c.id]
                for t, c in channels.items()} == recorder.counts
        for topic, channel in channels.items():
            schema = summary.schemas[channel.schema_id]
            assert channel.message_encoding == 'cdr' and schema.encoding == 'ros2msg'
            assert channel.metadata['topic_type_hash'] == generated_type_hash(schema.name)
            assert yaml.safe_load(channel.metadata['offered_qos_profiles']) == [{
                'history': 'unknown', 'depth': 0, 'reliability': 'reliable',
                'durability': 'volatile', 'deadline': {'sec': 9223372036, 'nsec': 854775807},
                'lifespan': {'sec': 9223372036, 'nsec': 854775807}, 'liveliness': 'automatic',
                'liveliness_lease_duration': {'sec': 9223372036, 'nsec': 854775807},
                'avoid_ros_namespace_conventions': False}]
        (stored,) = [m for m in reader.iter_metadata() if m.name == 'rosbag2']
        assert yaml.safe_load(stored.metadata['serialized_metadata']) == info
        counts = dict.fromkeys(channels, 0)
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            assert message.sequence == 0
            reference = STORE.deserialize_cdr(message.data, schema.name)
            assert decoded.header.stamp.sec == reference.header.stamp.sec
            assert decoded.header.stamp.nanosec == reference.header.stamp.nanosec
            if schema.name == JOINT_STATE:
                np.testing.assert_array_equal(decoded.position, reference.position)
        assert counts == recorder.counts


def test_publish_time_is_the_send_time(tmp_path):
    path = tmp_path / 'times'
    written = [(1_000_000 + 10 * i, 999_000 + 7 * i) for i in range(1000)]
    message = STORE.serialize_cdr(STORE.types[JOINT_STATE](
        header=STORE.types['std_msgs/msg/Header'](
            stamp=STORE.types['builtin_interfaces/msg/Time'](sec=1, nanosec=2), frame_id='b'),
        name=[], position=np.zeros(0), velocity=np.zeros(0), effort=np.zeros(0)),
        JOINT_STATE)
    with BagRecorder(path, 'mcap') as recorder:
        recorder.add_topic('/joint_states', JOINT_STATE)
        recorder.add_topic('/other', JOINT_STATE)
        for log_time, publish_time in written:
            recorder.write('/joint_states', log_time, message, publish_time)
        recorder.write('/other', 5, message)
    with open(path / 'times_0.mcap', 'rb') as stream:
        times = {}
        for _, channel, message in make_reader(stream).iter_messages(log_time_order=False):
            times.setdefault(channel.topic, []).append((message.log_time, message.publish_time))
    assert times == {'/joint_states': written, '/other': [(5, 5)]}


def test_the_publishers_count_is_the_mcap_sequence_and_read_back(tmp_path):
    # DDS's publication sequence numbers, one lost (4), and one the recorder did not know (0).
    path = tmp_path / 'counted'
    message = STORE.serialize_cdr(STORE.types[JOINT_STATE](
        header=STORE.types['std_msgs/msg/Header'](
            stamp=STORE.types['builtin_interfaces/msg/Time'](sec=1, nanosec=2), frame_id='b'),
        name=[], position=np.zeros(0), velocity=np.zeros(0), effort=np.zeros(0)),
        JOINT_STATE)
    counts = [1, 2, 3, 5, 0, 2**32 + 6]
    with BagRecorder(path, 'mcap') as recorder:
        recorder.add_topic('/joint_states', JOINT_STATE)
        for log_time, count in enumerate(counts):
            recorder.write('/joint_states', 100 + log_time, message, sequence=count)
    with open(path / 'counted_0.mcap', 'rb') as stream:
        recorded = [m.sequence for _, _, m in make_reader(stream).iter_messages()]
    assert recorded == [1, 2, 3, 5, 0, 6]  # MCAP's sequence has 32 bits
    read = read_topics(path, ['/joint_states'])['/joint_states']
    assert read.sequence.tolist() == recorded


def test_sqlite3_schema_is_rosbag2_jazzys(bags):
    path, recorder = bags['sqlite3']
    database = sqlite3.connect(path / 'session_a_0.db3')
    try:
        assert [sql for (sql,) in database.execute('SELECT sql FROM sqlite_master')] == (
            JAZZY_SQLITE3_TABLES)
        assert list(database.execute('SELECT * FROM schema')) == [(4, 'jazzy')]
        ((version, stored),) = database.execute('SELECT metadata_version, metadata FROM metadata')
        assert version == 9 and yaml.safe_load(stored) == metadata_yaml(path)
        for name, msgtype, type_hash in database.execute(
                'SELECT name, type, type_description_hash FROM topics'):
            assert type_hash == generated_type_hash(msgtype)
        definitions = list(database.execute(
            'SELECT topic_type, encoding, type_description_hash FROM message_definitions'))
        assert sorted(definitions) == sorted(
            (msgtype, 'ros2msg', generated_type_hash(msgtype)) for msgtype in
            (JOINT_STATE, POSE_STAMPED, WRENCH_STAMPED, DIAGNOSTIC_ARRAY))
        counts = dict(database.execute(
            'SELECT topics.name, count(*) FROM messages JOIN topics ON topic_id = topics.id '
            'GROUP BY topics.name'))
        assert counts == recorder.counts
    finally:
        database.close()


def test_message_definitions_are_the_installed_msg_files():
    encoding, text = message_definition(JOINT_STATE)
    sections = text.split('\n' + '=' * 80 + '\n')
    assert encoding == 'ros2msg'
    assert [s.partition('\n')[0] for s in sections[1:]] == [
        'MSG: std_msgs/Header', 'MSG: builtin_interfaces/Time']
    try:
        share = _share_directory('sensor_msgs')
    except LookupError:
        pytest.skip('sensor_msgs is not installed where the ament index finds it')
    assert sections[0] == (share / 'msg' / 'JointState.msg').read_text()
